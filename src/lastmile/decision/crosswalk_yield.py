"""Who the shuttle yields to at a crosswalk: people on it, stepping onto it, or about to be.

A pedestrian or cyclist (or an unclassified object) counts while inside the crosswalk grown by
``margin_m``, or when either of two futures brings them there before the shuttle has cleared the
crossing (at most ``lookahead_s`` ahead): their constant-velocity path, or the map-aware prediction's
``to_crosswalk`` path (someone making for the crossing may turn towards it, or hurry up to cross).
Either future is enough; neither can cancel the other. A crosswalk the shuttle's front is already on
is cleared rather than stopped on.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lastmile.core.geometry import point_in_polygon
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TrackedObjects
from lastmile.core.polyline import Polyline
from lastmile.core.predictions import PREDICTION_MODES, PredictedPaths
from lastmile.hdmap.layers import RouteCrosswalk

_CROSS = PREDICTION_MODES.index("to_crosswalk")
SEARCH_M = 40.0
"""Crosswalks farther ahead of the front than this are not looked at yet."""
STEP_S = 0.5
"""Sampling of the constant-velocity future."""


def crosswalk_yields(
    crosswalks: Sequence[RouteCrosswalk],
    route: Polyline,
    tracks: TrackedObjects,
    front_s_m: float,
    speed_mps: float,
    shuttle_length_m: float,
    predictions: PredictedPaths | None,
    *,
    margin_m: float,
    lookahead_s: float,
) -> list[tuple[float, int]]:
    """(stop point in route s, 1 m before the crossing; the first track that makes the shuttle yield)
    per crosswalk ahead that someone is on or about to be on."""
    out: list[tuple[float, int]] = []
    to_crossing = _to_crosswalk(predictions)
    for rc in crosswalks:
        ahead = route.ds_m(front_s_m, rc.s_start_m)
        if ahead > SEARCH_M or ahead < -0.5:
            continue  # not yet, or already on it: clear it rather than stop on it
        poly = rc.crosswalk.polygon
        to_clear_m = ahead + (rc.s_end_m - rc.s_start_m) + shuttle_length_m
        horizon_s = min(lookahead_s, to_clear_m / max(speed_mps, 1.0))
        steps_s = np.arange(0.0, horizon_s + 1e-9, STEP_S)
        for tid, row in zip(tracks.ids.tolist(), tracks.table.tolist(), strict=True):
            cls = ObjectClass(int(row[7]))
            if not (cls.vulnerable or cls == ObjectClass.UNKNOWN):
                continue
            ahead_xy = [(row[0] + row[2] * t, row[1] + row[3] * t) for t in steps_s]
            path = to_crossing.get(int(tid))
            if path is not None:
                ahead_xy += [(x, y) for t, x, y in path.tolist() if t <= horizon_s + 1e-9]
            if any(_near_polygon(x, y, poly, margin_m) for x, y in ahead_xy):
                out.append((rc.s_start_m - 1.0, int(tid)))
                break
    return out


def _to_crosswalk(predictions: PredictedPaths | None) -> dict[int, np.ndarray]:
    """Track id -> (T, 3) rows ``t x y`` of the paths the prediction sends to a crossing."""
    if predictions is None:
        return {}
    t = predictions.times_s[:, None]
    return {
        int(tid): np.hstack([t, xy])
        for tid, mode, xy in zip(predictions.ids, predictions.mode, predictions.xy_m, strict=True)
        if int(mode) == _CROSS
    }


def _near_polygon(x: float, y: float, poly: np.ndarray, margin_m: float) -> bool:
    """Inside the polygon, or inside its bounding box grown by ``margin_m``."""
    if point_in_polygon(x, y, poly):
        return True
    lo = poly.min(axis=0) - margin_m
    hi = poly.max(axis=0) + margin_m
    return bool(lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1])
