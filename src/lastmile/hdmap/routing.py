"""A* over the lanelet successor graph, and routes turned into one drivable centre line.

Edge cost is the length of the lanelet entered; the heuristic (straight-line distance from a lanelet's
end to the goal's start, plus the goal's length) never overestimates, so A* returns the same
shortest route as Lanelet2's Dijkstra (a test checks this on the Lanelet2 example map) while
expanding fewer lanelets.
"""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import RoutingError
from lastmile.core.polyline import Polyline
from lastmile.hdmap import campus_layout, corner_rounding, lane_change
from lastmile.hdmap.model import HDMap

JOIN_TOLERANCE_M = 1e-6
LANE_CHANGE_COST_M = 10.0
"""Extra cost of a lane change in metres of driving: Lanelet2's default (``defaultRoutingCosts``:
``RoutingCostDistance(10.)``)."""
LANE_CHANGE_SHARE = 1.0 / 2.0
"""A lane change leaves its lanelet half way along what is left of it and joins the lanelet beside
abreast of that point; ``lane_change`` turns the sideways step into a transition of its own length."""


@dataclass(frozen=True, slots=True, kw_only=True)
class RoutePiece:
    """The part of one lanelet's centre line a route drives: s from ``s0_m`` to ``s1_m`` on it."""

    lanelet_id: int
    s0_m: float
    s1_m: float

    @property
    def whole(self) -> bool:
        return self.s0_m == 0.0 and self.s1_m == math.inf

    def length_m(self, hdmap: HDMap) -> float:
        return min(self.s1_m, hdmap.lanelets[self.lanelet_id].centerline.length_m) - self.s0_m


def route(hdmap: HDMap, start_id: int, goal_id: int, lane_changes: bool = False) -> tuple[int, ...]:
    """Shortest lanelet sequence from ``start_id`` to ``goal_id`` (both included) following successors.

    With ``lane_changes`` a step may also go to a lanelet beside (``HDMap.neighbours``), at the extra
    cost LANE_CHANGE_COST_M, so that routes change lanes only where they must (aUToronto 7.1.2
    discourages lane changes; Lanelet2 prices one alike).

    Raises:
        RoutingError: an id is not in the map, or the goal cannot be reached from the start.
    """
    for label, lid in (("start", start_id), ("goal", goal_id)):
        if lid not in hdmap.lanelets:
            raise RoutingError(f"route {label}: expected a lanelet id of map {hdmap.name!r}, got {lid}")
    if start_id == goal_id:
        return (start_id,)
    goal = hdmap.lanelets[goal_id].centerline
    gx, gy = goal.xy_m[0]
    goal_len = goal.length_m

    def heuristic(lid: int) -> float:
        if lid == goal_id:
            return 0.0
        ex, ey = hdmap.lanelets[lid].centerline.xy_m[-1]
        return math.hypot(gx - ex, gy - ey) + goal_len

    g_cost = {start_id: 0.0}
    parent: dict[int, int] = {}
    frontier = [(heuristic(start_id), 0, start_id)]
    pushed = 1
    closed: set[int] = set()
    while frontier:
        _, _, lid = heapq.heappop(frontier)
        if lid == goal_id:
            path = [lid]
            while path[-1] != start_id:
                path.append(parent[path[-1]])
            return tuple(reversed(path))
        if lid in closed:
            continue
        closed.add(lid)
        here = hdmap.lanelets[lid].centerline.length_m
        steps = [(n, hdmap.lanelets[n].centerline.length_m) for n in hdmap.successors(lid)]
        if lane_changes:
            # Beside a lanelet one is as far along as in it: pay only what the new lane is longer.
            steps += [
                (n, LANE_CHANGE_COST_M + max(hdmap.lanelets[n].centerline.length_m - here, 0.0))
                for n in hdmap.neighbours(lid)
            ]
        for nxt, step in steps:
            cost = g_cost[lid] + step
            if cost < g_cost.get(nxt, math.inf):
                g_cost[nxt] = cost
                parent[nxt] = lid
                heapq.heappush(frontier, (cost + heuristic(nxt), pushed, nxt))
                pushed += 1
    raise RoutingError(f"route: expected lanelet {goal_id} reachable from {start_id}, got no path")


def route_length_m(hdmap: HDMap, lanelet_ids: tuple[int, ...]) -> float:
    return float(sum(p.length_m(hdmap) for p in route_pieces(hdmap, lanelet_ids)))


def _is_lane_change(hdmap: HDMap, a: int, b: int) -> bool:
    return b not in hdmap.successors(a) and b in hdmap.neighbours(a)


def route_pieces(hdmap: HDMap, lanelet_ids: tuple[int, ...], closed: bool = False) -> tuple[RoutePiece, ...]:
    """What of each lanelet the route drives: all of it, except around lane changes.

    A lanelet entered from its predecessor is driven from its start; one left by a lane change is left
    LANE_CHANGE_SHARE along what remained, and the lanelet beside is joined abreast of that point.
    Whole pieces carry ``s1_m = inf`` (to the lanelet's end).

    Raises:
        RoutingError: the sequence is empty, names an unknown lanelet, or has a step that is neither
            a successor nor a permitted lane change; a closed route that closes with a lane change.
    """
    if not lanelet_ids:
        raise RoutingError("route: expected at least one lanelet id, got none")
    links = list(itertools.pairwise(lanelet_ids))
    if closed and len(lanelet_ids) > 1:
        links.append((lanelet_ids[-1], lanelet_ids[0]))
    for a, b in links:
        if a not in hdmap.lanelets or b not in hdmap.lanelets:
            raise RoutingError(f"route: expected lanelet ids of map {hdmap.name!r}, got {a} and {b}")
        if b not in hdmap.successors(a) and b not in hdmap.neighbours(a):
            raise RoutingError(f"route_polyline: expected lanelet {b} to follow lanelet {a}, it does not")
    if closed and len(lanelet_ids) > 1 and _is_lane_change(hdmap, lanelet_ids[-1], lanelet_ids[0]):
        raise RoutingError(
            f"route: expected a closed route to close along a successor, got a lane change from "
            f"{lanelet_ids[-1]} to {lanelet_ids[0]}"
        )
    pieces = []
    start_frac = 0.0
    for k, lid in enumerate(lanelet_ids):
        length = hdmap.lanelets[lid].centerline.length_m
        nxt = lanelet_ids[k + 1] if k + 1 < len(lanelet_ids) else None
        if nxt is not None and _is_lane_change(hdmap, lid, nxt):
            leave = start_frac + (1.0 - start_frac) * LANE_CHANGE_SHARE
            pieces.append(RoutePiece(lanelet_id=lid, s0_m=start_frac * length, s1_m=leave * length))
            # Join the lanelet beside where it is abreast of the point left: the step is sideways only.
            x, y, _ = hdmap.lanelets[lid].centerline.point_at(leave * length)
            beside = hdmap.lanelets[nxt].centerline
            start_frac = min(max(beside.project(x, y).s_m / beside.length_m, 0.0), 1.0 - 1e-6)
        else:
            s0 = start_frac * length
            pieces.append(RoutePiece(lanelet_id=lid, s0_m=s0 if start_frac else 0.0, s1_m=math.inf))
            start_frac = 0.0
    return tuple(pieces)


def _piece_xy(hdmap: HDMap, piece: RoutePiece) -> np.ndarray:
    line = hdmap.lanelets[piece.lanelet_id].centerline
    if piece.whole:
        return line.xy_m
    s1 = min(piece.s1_m, line.length_m)
    inner = (line.s_m > piece.s0_m) & (line.s_m < s1)
    return np.vstack(
        [line.points_at(np.array([piece.s0_m])), line.xy_m[inner], line.points_at(np.array([s1]))]
    )


def route_polyline(
    hdmap: HDMap,
    lanelet_ids: tuple[int, ...],
    closed: bool = False,
    unmapped_speed_limit_mps: float | None = None,
    keep_clear: tuple[lane_change.KeepClear, ...] = (),
    steerable: bool = False,
) -> Polyline:
    """The route's centre line: the lanelets' centre lines joined end to end; a lane change is a
    smooth lateral transition from one lane's line to the other's (``lane_change``), as long as its
    speed limit asks and placed where the shuttle stays on the road, across lanelet boundaries.

    Args:
        unmapped_speed_limit_mps: the speed on lanelets whose map states no limit (a route file's);
            only lane changes need a speed.
        keep_clear: stretches (stop platforms) lane changes keep out of where the road allows.
        steerable: round the corners the shuttle cannot steer (``corner_rounding``): a shuttle's
            service route; other road users' paths keep the mapped lines.

    Raises:
        RoutingError: the sequence is empty, names an unknown lanelet, or skips a successor link; a
            lane change leaves a lanelet with no speed limit, mapped or given.
    """
    pieces = route_pieces(hdmap, lanelet_ids, closed)
    parts = [_piece_xy(hdmap, p) for p in pieces]
    # Consecutive lanelets share their end points; a link bridged over a gap (a route file's
    # connect_gaps_m) keeps both, and the joined line crosses straight.
    joined = [parts[0]]
    jumps: list[lane_change.LaneJump] = []
    at = len(parts[0])
    links = list(itertools.pairwise(range(len(parts))))
    for i, j in links:
        prev, part = parts[i], parts[j]
        if _is_lane_change(hdmap, pieces[i].lanelet_id, pieces[j].lanelet_id):
            speed = _lane_change_speed(hdmap, pieces[i].lanelet_id, unmapped_speed_limit_mps)
            jumps.append(
                lane_change.LaneJump(
                    index=at,
                    speed_mps=speed,
                    from_lanelet_id=pieces[i].lanelet_id,
                    to_lanelet_id=pieces[j].lanelet_id,
                )
            )
        keep = part[1:] if float(np.hypot(*(part[0] - prev[-1]))) < JOIN_TOLERANCE_M else part
        joined.append(keep)
        at += len(keep)
    xy = np.vstack(joined)
    if closed:
        xy = xy[:-1]
    if jumps:
        xy = lane_change.smooth_lane_changes(hdmap, xy, jumps, closed, keep_clear=keep_clear)
    if steerable:
        xy = corner_rounding.round_corners(hdmap, xy, closed)
    return Polyline(xy, closed=closed)


def _lane_change_speed(hdmap: HDMap, lanelet_id: int, unmapped_mps: float | None) -> float:
    mapped = hdmap.lanelets[lanelet_id].speed_limit_mps
    if math.isfinite(mapped):
        return float(mapped)
    if unmapped_mps is None:
        raise RoutingError(
            f"route: expected a speed limit on lanelet {lanelet_id} to shape its lane change (mapped, or "
            "the route file's unmapped_speed_limit_kph), got none"
        )
    return unmapped_mps


def lanelet_starts_m(hdmap: HDMap, lanelet_ids: tuple[int, ...]) -> np.ndarray:
    """(N+1,) route s where each lanelet's piece begins, then the route's end."""
    lengths = [p.length_m(hdmap) for p in route_pieces(hdmap, lanelet_ids)]
    return np.concatenate([[0.0], np.cumsum(lengths)])


def campus_shuttle_loop(hdmap: HDMap) -> tuple[int, ...]:
    """The campus service loop: the ring's outer lane, counter-clockwise from the south-west corner.

    Raises:
        RoutingError: ``hdmap`` is not the campus map (no outer-lane lanelet where the loop starts).
    """
    ring = campus_layout.RING
    ids = []
    for s in (1.0, ring.length_m / 2):
        x, y, h = ring.pose(s)
        px, py = (
            x + 0.5 * campus_layout.LANE_W_M * math.sin(h),
            y - 0.5 * campus_layout.LANE_W_M * math.cos(h),
        )
        lid = hdmap.lanelet_at(px, py)
        if lid is None:
            raise RoutingError(
                f"campus_shuttle_loop: expected the campus ring at ({px:.1f}, {py:.1f}), got no lanelet"
            )
        ids.append(lid)
    there = route(hdmap, ids[0], ids[1])
    back = route(hdmap, ids[1], ids[0])
    return there + back[1:-1]
