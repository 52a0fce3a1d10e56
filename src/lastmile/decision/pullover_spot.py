"""WATonoBus's dynamic pull-over spot: scan the stop for obstacles and pick a free, reachable place."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.route_obstacles import RouteObstacle


@dataclass(frozen=True, slots=True, kw_only=True)
class SpotRequest:
    """The stop's platform in route s and the shuttle's needs.

    Attributes:
        platform_start_s_m, platform_end_s_m: platform extent along the route.
        bay_edge_d_m: route d of the lane's right edge; anything right of it is in the bay.
        curb_d_m: route d of the bay's curb (people on the platform beyond it do not block).
        vehicle_length_m: shuttle length.
        transition_m: route length the lateral move into the bay needs, kept clear of obstacles.
        margin_m: clearance to obstacles in front of and behind the chosen spot.
        exit_m: further room kept free ahead of the front bumper, so that the merge curve has left the
            bay before it reaches a car parked further along it.
        earliest_front_s_m: the nearest front position the shuttle can still stop at.
        preferred_front_s_m: where the front bumper goes when the stop is empty (door mid-platform).
    """

    platform_start_s_m: float
    platform_end_s_m: float
    bay_edge_d_m: float
    curb_d_m: float
    vehicle_length_m: float
    transition_m: float
    margin_m: float
    preferred_front_s_m: float
    exit_m: float = 0.0
    earliest_front_s_m: float = -math.inf


def choose_spot(request: SpotRequest, obstacles: list[RouteObstacle], step_m: float = 0.5) -> float | None:
    """Route s of the front bumper at the best free spot, or None when the stop has no room.

    Only obstacles in the bay (right of the lane edge) block; among free spots the one nearest the
    preferred place wins, ties going to the earlier spot (less distance to drive in the bay).
    """
    r = request
    blocked: list[tuple[float, float]] = []
    for o in obstacles:
        in_bay = o.d_m - o.width_m / 2.0 < r.bay_edge_d_m and o.d_m + o.width_m / 2.0 > r.curb_d_m
        if in_bay:
            blocked.append((o.s_m - o.length_m / 2.0 - r.margin_m, o.s_m + o.length_m / 2.0 + r.margin_m))
    lo = max(r.platform_start_s_m + r.vehicle_length_m, r.earliest_front_s_m)
    hi = r.platform_end_s_m
    candidates: list[float] = []
    s = lo
    while s <= hi + 1e-9:
        body = (s - r.vehicle_length_m, s + r.exit_m)
        approach = (s - r.vehicle_length_m - r.transition_m, s - r.vehicle_length_m)
        if not any(_overlap(body, b) or _overlap(approach, b) for b in blocked):
            candidates.append(s)
        s += step_m
    if not candidates:
        return None
    return min(candidates, key=lambda c: (abs(c - r.preferred_front_s_m), c))


def _overlap(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[0] < b[1] and b[0] < a[1]
