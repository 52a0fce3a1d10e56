"""Who the shuttle yields to at a crosswalk: people on it, stepping onto it, or about to be.

A pedestrian or cyclist (or an unclassified object) counts while inside the crosswalk grown by
``margin_m``, or when either of two futures brings them there before the shuttle has cleared the
crossing (at most ``lookahead_s`` ahead): their constant-velocity path, or the map-aware prediction's
``to_crosswalk`` path (someone making for the crossing may turn towards it, or hurry up to cross).
Either future is enough; neither can cancel the other. A crosswalk the shuttle's front is already on
is cleared rather than stopped on.

Where it stops: 1 m before the crossing, and no nearer to the person it yields to than the in-path
rule would keep once they step into the path (eq. (2)'s ``gap_m`` from their near end, at the crossing's
near edge at the latest) while that point is still ahead and comfortably reachable (otherwise at the
line, as a shuttle restarting after a yield must not get a stop point behind its front). Without the
second bound, a pedestrian walking across the crossing and into the path moved the stop point ~0.5 m
closer in the last metre of a stop at ~1 m/s: a stop that had faded out had to brake again at
~1 m/s^2 and ended with a jerk of up to 7.7 m/s^3.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lastmile.core.geometry import point_in_polygon
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.polyline import Polyline
from lastmile.core.predictions import PREDICTION_MODES, PredictedPaths
from lastmile.hdmap.layers import RouteCrosswalk

_CROSS = PREDICTION_MODES.index("to_crosswalk")
SEARCH_M = 40.0
"""Crosswalks farther ahead of the front than this are not looked at yet."""
STEP_S = 0.5
"""Sampling of the constant-velocity future."""
_LENGTH = TRACK_COLUMNS.index("length_m")


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
    gap_m: float,
    comfort_decel_mps2: float,
    unsettled: frozenset[int] = frozenset(),
    unsettled_room_m: float = 0.0,
) -> list[tuple[float, int]]:
    """(stop point in route s; the first track that makes the shuttle yield) per crosswalk ahead that
    someone is on or about to be on. The stop point is 1 m before the crossing, or ``gap_m`` before
    that track's near end (taken at the crossing's near edge at the latest) when that is nearer the
    shuttle and can still be stopped at with ``comfort_decel_mps2`` (v^2 / 2d; a stop already braking
    for it keeps it, one already past it, restarting after a yield, falls back to the line).

    A track in ``unsettled`` (an unclassified one only just tracked) is yielded to only while the line
    is at least ``unsettled_room_m`` ahead, a comfortable stop's length: a precipitation echo that the
    tracker briefly follows must not brake the shuttle at the urgent rate, and a person still that
    close once tracked for a while (or classified) is yielded to then, or is the in-path rule's."""
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
        too_close_for_unsettled = route.ds_m(front_s_m, rc.s_start_m - 1.0) < unsettled_room_m
        for tid, row in zip(tracks.ids.tolist(), tracks.table.tolist(), strict=True):
            cls = ObjectClass(int(row[7]))
            if not (cls.vulnerable or cls == ObjectClass.UNKNOWN):
                continue
            if too_close_for_unsettled and int(tid) in unsettled:
                continue
            ahead_xy = [(row[0] + row[2] * t, row[1] + row[3] * t) for t in steps_s]
            path = to_crossing.get(int(tid))
            if path is not None:
                ahead_xy += [(x, y) for t, x, y in path.tolist() if t <= horizon_s + 1e-9]
            if any(_near_polygon(x, y, poly, margin_m) for x, y in ahead_xy):
                back_s = _back_off_s_m(route, rc, row, gap_m, margin_m)
                room_m = route.ds_m(front_s_m, back_s)
                fits = room_m > 0.0 and speed_mps**2 / (2.0 * room_m) <= comfort_decel_mps2
                out.append((min(back_s, rc.s_start_m - 1.0) if fits else rc.s_start_m - 1.0, int(tid)))
                break
    return out


def _back_off_s_m(
    route: Polyline, rc: RouteCrosswalk, row: list[float], gap_m: float, margin_m: float
) -> float:
    """``gap_m`` before the yielded-to track's near end: where the in-path rule will want the shuttle
    once that person is in its path. Their
    position along the route is taken inside the zone that counts as the crossing (its near edge, or
    ``margin_m`` before it at most): someone further off is not where they will step in."""
    along_m = route.ds_m(rc.s_start_m, route.project(row[0], row[1], hint_s_m=rc.s_start_m).s_m)
    near_end_m = min(max(along_m, -margin_m), 0.0) - row[_LENGTH] / 2.0
    return rc.s_start_m + near_end_m - gap_m


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
