"""Vehicles about to enter the shuttle's path, from tracking's lane-following prediction.

The decision's in-path test sees a vehicle once it is inside the corridor swept along the planned
path, and predicts nothing for vehicles (only pedestrians and cyclists get a constant-velocity look
ahead there). A car turning in from a side road, or leaving a lanelet that joins the shuttle's, is
then seen only as it arrives, often too close to stop comfortably. Tracking's map-aware prediction
(``tracking.prediction``) already says where such a car goes: along its lanelet into the straightest
successor, braking for a stop line on its way. Here each lane-following path is walked in time; where
it first enters the corridor ahead of the shuttle's front, and the car gets there before the shuttle
could pass (``pass_margin_s`` included), the car counts as a lead at that point, moving on along the
route at its predicted speed there. Crossing traffic is the exception: a path that leaves the
corridor again (a car turning left across the lane) is let through without a constraint when it will
have left at least ``pass_margin_s`` before the shuttle's front gets to the crossing point.

Left to the other rules: a vehicle already in the corridor (the in-path test), one at or behind the
shuttle's front (merging checks the rear), and paths the prediction stops at a stop line short of the
corridor (a car waiting to turn in gets no constraint until it moves).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.polyline import FrenetPoint, Polyline
from lastmile.core.predictions import PREDICTION_MODES, PredictedPaths
from lastmile.core.route_obstacles import RouteObstacle

_LANE = PREDICTION_MODES.index("lane_following")


@dataclass(frozen=True, slots=True, kw_only=True)
class CutIn:
    """Where a vehicle's predicted path enters the shuttle's corridor.

    Attributes:
        track_id: the vehicle's track.
        entry_s_m: route position (same frame as the route's ``s``) of the first predicted centre
            inside the corridor.
        entry_t_s: when the prediction puts it there.
        ahead_m: distance from the shuttle's front to the entry, along the route.
        speed_along_mps: its predicted speed along the route after entering (negative: towards the
            shuttle).
        length_m: the vehicle's length.
    """

    track_id: int
    entry_s_m: float
    entry_t_s: float
    ahead_m: float
    speed_along_mps: float
    length_m: float


def predicted_cut_ins(
    obstacles: list[RouteObstacle],
    predictions: PredictedPaths | None,
    route: Polyline,
    path: Polyline | None,
    front_s_m: float,
    speed_mps: float,
    half_width_m: float,
    *,
    horizon_s: float,
    pass_margin_s: float,
    lookahead_m: float = 70.0,
) -> list[CutIn]:
    """The vehicles whose lane-following path enters the corridor ahead before the shuttle passes.

    Args:
        obstacles: the tracks projected on the route (``route_obstacles``), for their current place.
        predictions: tracking's predicted paths (None: no prediction, no cut-ins).
        route: the route the obstacles were projected on.
        path: the planned path, when there is one (its lateral offset from the route, in a pull-over
            or a nudge, moves the corridor with it).
        front_s_m: the shuttle's front on the route.
        speed_mps: the shuttle's speed (at least 1 m/s is assumed, to time a shuttle that is stopped).
        half_width_m: half the shuttle's width plus the corridor margin; the vehicle's own half width
            is added per vehicle.
        horizon_s: how far ahead in time the paths are used.
        pass_margin_s: the car must reach the entry at least this long after the shuttle's front
            would, or the shuttle yields to it; a crossing car must have left the corridor at least
            this long before the front gets there, or the shuttle waits for it.
        lookahead_m: entries farther ahead than this along the route are ignored.
    """
    if predictions is None or len(predictions) == 0:
        return []
    by_id = {o.track_id: o for o in obstacles}
    times = predictions.times_s.tolist()
    shuttle = _Shuttle(route, path, front_s_m, max(speed_mps, 1.0), horizon_s, pass_margin_s, lookahead_m)
    out: list[CutIn] = []
    rows = zip(predictions.ids.tolist(), predictions.mode.tolist(), predictions.xy_m, strict=True)
    for tid, mode, xy in rows:
        o = by_id.get(int(tid))
        if int(mode) != _LANE or o is None or o.cls.vulnerable or o.ds_m <= 0.0:
            continue
        half = half_width_m + o.width_m / 2.0
        if abs(_lateral(path, o.x_m, o.y_m, o.d_m)) < half:
            continue  # already in the corridor: the in-path test's
        cut_in = _cut_in(shuttle, o, xy.tolist(), times, half)
        if cut_in is not None:
            out.append(cut_in)
    return out


@dataclass(frozen=True, slots=True)
class _Shuttle:
    """The shuttle's side of the test: its route, planned path, front, speed (at least 1 m/s) and the
    limits of :func:`predicted_cut_ins`."""

    route: Polyline
    path: Polyline | None
    front_s_m: float
    speed_mps: float
    horizon_s: float
    pass_margin_s: float
    lookahead_m: float


def _cut_in(
    shuttle: _Shuttle, o: RouteObstacle, pts: list[list[float]], times: list[float], half: float
) -> CutIn | None:
    """The cut-in of one vehicle's path (``pts`` at ``times``), or None when it does not cut in."""
    # Each predicted centre projected on the route once. The corridor test (a projection on the
    # planned path, the costly part) runs on samples up to the entry, then on those after it: each
    # sample at most once.
    route = shuttle.route
    frenet = _along_route(route, pts, o.s_m)
    entry = _entry(shuttle, pts, frenet, times, half)
    if entry is None:
        return None
    t_s, ahead_m, k = entry
    # Crossing traffic: when the path is first outside the corridor again (never: it turns in).
    t_out = next(
        (times[j] for j in range(k + 1, len(times)) if not _inside(shuttle.path, pts[j], frenet[j], half)),
        math.inf,
    )
    if ahead_m / shuttle.speed_mps >= t_out + shuttle.pass_margin_s:
        return None  # it will have left the corridor before the shuttle gets there
    # Speed along the route there: finite difference with the next sample (the previous at the end).
    j = k + 1 if k + 1 < len(times) else k - 1
    speed_along = route.ds_m(frenet[k].s_m, frenet[j].s_m) / (times[j] - times[k]) if j >= 0 else 0.0
    return CutIn(
        track_id=int(o.track_id),
        entry_s_m=frenet[k].s_m,
        entry_t_s=t_s,
        ahead_m=ahead_m,
        speed_along_mps=speed_along,
        length_m=o.length_m,
    )


def _entry(
    shuttle: _Shuttle, pts: list[list[float]], frenet: list[FrenetPoint], times: list[float], half: float
) -> tuple[float, float, int] | None:
    """(time, distance ahead of the front, sample) of the path's first centre inside the corridor
    ahead, within the horizon and the lookahead; None when there is none, or when the shuttle's
    front passes that point ``pass_margin_s`` before the car gets there."""
    for k, (t, f) in enumerate(zip(times, frenet, strict=True)):
        if t > shuttle.horizon_s + 1e-9:
            return None
        ahead = shuttle.route.ds_m(shuttle.front_s_m, f.s_m)
        if not 0.0 < ahead <= shuttle.lookahead_m or not _inside(shuttle.path, pts[k], f, half):
            continue
        if t >= ahead / shuttle.speed_mps + shuttle.pass_margin_s:
            return None  # the shuttle passes the entry first: the car comes in behind it
        return (t, ahead, k)
    return None


def _along_route(route: Polyline, pts: list[list[float]], hint_s_m: float) -> list[FrenetPoint]:
    """Route Frenet coordinates of consecutive points, each searched near the one before."""
    out = []
    for x, y in pts:
        f = route.project(x, y, hint_s_m=hint_s_m, window_m=30.0)
        hint_s_m = f.s_m
        out.append(f)
    return out


def _inside(path: Polyline | None, pt: list[float], f: FrenetPoint, half_m: float) -> bool:
    """Whether a predicted centre (``f``: its route coordinates) is inside the corridor."""
    return abs(_lateral(path, pt[0], pt[1], f.d_m)) < half_m


def _lateral(path: Polyline | None, x_m: float, y_m: float, route_d_m: float) -> float:
    """Offset of a point from the planned path (from the route when there is no path)."""
    return path.project(x_m, y_m).d_m if path is not None else route_d_m
