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

import math
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
_SLOW_MPS = 0.1
"""Below this the shuttle is taken as standing: it clears nothing first."""
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
    comfortable_room_m: float = 0.0,
    corridor_half_m: float = 0.0,
    pass_margin_s: float = math.inf,
    yielding_to: frozenset[int] = frozenset(),
) -> list[tuple[float, int]]:
    """(stop point in route s; the first track that makes the shuttle yield) per crosswalk ahead that
    someone is on or about to be on. The stop point is 1 m before the crossing, or ``gap_m`` before
    that track's near end (taken at the crossing's near edge at the latest) when that is nearer the
    shuttle and can still be stopped at with ``comfort_decel_mps2`` (v^2 / 2d; a stop already braking
    for it keeps it, one already past it, restarting after a yield, falls back to the line).

    A track in ``unsettled`` (an unclassified one only just tracked) is yielded to only while the line
    is at least ``comfortable_room_m`` ahead, a comfortable stop's length: a precipitation echo that
    the tracker briefly follows must not brake the shuttle at the urgent rate, and a person still that
    close once tracked for a while (or classified) is yielded to then, or is the in-path rule's. A
    yield under way (``yielding_to``: the track the last cycle yielded to) is not dropped for that.

    A shuttle whose front is past the line but not yet on the crossing (moving off after a yield)
    stops at the crossing's near edge while a comfortable stop still fits before it (for an unsettled
    track too), not at the line behind its front: that is an overshoot, which the speed law brakes back
    from as hard as it may (snow, seed 2, a_nom 1.0: a person first tracked as unclassified, ignored at
    0.2 m/s as the line was behind, settled as the shuttle moved off at 0.9 m/s, -2.76 m/s^3). The
    point is fixed: one kept a comfortable stop ahead of the front moved off with it.

    A yield that no comfortable stop fits (the stop point nearer than ``comfortable_room_m``) is not
    made for someone neither of whose futures comes within ``corridor_half_m`` of the route (plus their
    own half length) before the shuttle, at the speed it has, has cleared the crossing and
    ``pass_margin_s`` more: the shuttle passes first, as Autoware's crosswalk module judges from the
    times both need to the conflict. A person appearing 4 m from the kerb as the shuttle came within
    10 m of the line at 5.5 m/s, 8 m from its path, was braked for at -2.28 m/s^2 and +18 m/s^3 (clear,
    seed 4, a_nom 1.0); they would have reached the path 2.5 s after the shuttle had cleared it. A
    shuttle moving with its front past the line is judged the same way (it was not: in clear seed 4,
    a_nom 1.0, a pass judged at 5.5 m/s turned, as the front passed the line, into 0.3 s of braking
    for the line behind it, -2.42 m/s^3); one standing or creeping off there yields as before."""
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
        line_s = rc.s_start_m - 1.0
        past_line = route.ds_m(front_s_m, line_s) < 0.0
        edge_m = route.ds_m(front_s_m, rc.s_start_m)
        if past_line and speed_mps >= _SLOW_MPS and edge_m >= comfortable_room_m:
            line_s, past_line = rc.s_start_m, False  # moving off past the line: the crossing's edge
        too_close_for_unsettled = route.ds_m(front_s_m, line_s) < comfortable_room_m
        pass_by_s = to_clear_m / max(speed_mps, _SLOW_MPS) + pass_margin_s  # no braking
        for tid, row in zip(tracks.ids.tolist(), tracks.table.tolist(), strict=True):
            cls = ObjectClass(int(row[7]))
            if not (cls.vulnerable or cls == ObjectClass.UNKNOWN):
                continue
            if too_close_for_unsettled and int(tid) in unsettled and int(tid) not in yielding_to:
                continue
            ahead_xy = [(row[0] + row[2] * t, row[1] + row[3] * t) for t in steps_s]
            path = to_crossing.get(int(tid))
            if path is not None:
                ahead_xy += [(x, y) for t, x, y in path.tolist() if t <= horizon_s + 1e-9]
            if any(_near_polygon(x, y, poly, margin_m) for x, y in ahead_xy):
                back_s = _back_off_s_m(route, rc, row, gap_m, margin_m)
                room_m = route.ds_m(front_s_m, back_s)
                fits = stop_fits(room_m, speed_mps, comfort_decel_mps2)
                stop_s = min(back_s, line_s) if fits and not past_line else line_s
                # Moving past the line, no stop fits before the crossing: the shuttle may pass first.
                moving = speed_mps >= _SLOW_MPS
                urgent = (moving or not past_line) and route.ds_m(front_s_m, stop_s) < comfortable_room_m
                if urgent and not _reaches_path_by(route, rc, row, path, pass_by_s, corridor_half_m):
                    continue  # the shuttle is through before they reach its path
                out.append((stop_s, int(tid)))
                break
    return out


def stop_fits(room_m: float, speed_mps: float, decel_mps2: float) -> bool:
    """A stop ``room_m`` ahead (m) needs no more than ``decel_mps2`` from ``speed_mps``: v^2 / (2 room)."""
    return room_m > 0.0 and speed_mps**2 / (2.0 * room_m) <= decel_mps2


def _reaches_path_by(
    route: Polyline,
    rc: RouteCrosswalk,
    row: list[float],
    predicted: np.ndarray | None,
    by_s: float,
    half_m: float,
) -> bool:
    """Whether the track's constant-velocity future, or its predicted path to the crossing (rows ``t x
    y``), comes within ``half_m`` of the route, plus its own half length, by ``by_s`` (a predicted
    path that ends sooner is not known to stay clear)."""
    if not math.isfinite(by_s):
        return True
    reach_m = half_m + row[_LENGTH] / 2.0
    xy = [(row[0] + row[2] * t, row[1] + row[3] * t) for t in np.arange(0.0, by_s + 1e-9, STEP_S)]
    if predicted is not None:
        if len(predicted) == 0 or predicted[-1, 0] < by_s:
            return True
        xy += [(x, y) for t, x, y in predicted.tolist() if t <= by_s + 1e-9]
    return any(abs(route.project(x, y, hint_s_m=rc.s_start_m).d_m) < reach_m for x, y in xy)


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
