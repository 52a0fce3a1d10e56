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

import numpy as np

from lastmile.core.errors import RoutingError
from lastmile.core.polyline import Polyline
from lastmile.hdmap import campus_layout
from lastmile.hdmap.model import HDMap

JOIN_TOLERANCE_M = 1e-6


def route(hdmap: HDMap, start_id: int, goal_id: int) -> tuple[int, ...]:
    """Shortest lanelet sequence from ``start_id`` to ``goal_id`` (both included) following successors.

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
        for nxt in hdmap.successors(lid):
            cost = g_cost[lid] + hdmap.lanelets[nxt].centerline.length_m
            if cost < g_cost.get(nxt, math.inf):
                g_cost[nxt] = cost
                parent[nxt] = lid
                heapq.heappush(frontier, (cost + heuristic(nxt), pushed, nxt))
                pushed += 1
    raise RoutingError(f"route: expected lanelet {goal_id} reachable from {start_id}, got no path")


def route_length_m(hdmap: HDMap, lanelet_ids: tuple[int, ...]) -> float:
    return float(sum(hdmap.lanelets[i].centerline.length_m for i in lanelet_ids))


def route_polyline(hdmap: HDMap, lanelet_ids: tuple[int, ...], closed: bool = False) -> Polyline:
    """The route's centre line: the lanelets' centre lines joined end to end.

    Raises:
        RoutingError: the sequence is empty, names an unknown lanelet, or skips a successor link.
    """
    if not lanelet_ids:
        raise RoutingError("route_polyline: expected at least one lanelet id, got none")
    links = list(itertools.pairwise(lanelet_ids))
    if closed and len(lanelet_ids) > 1:
        links.append((lanelet_ids[-1], lanelet_ids[0]))
    for a, b in links:
        if a not in hdmap.lanelets or b not in hdmap.lanelets or b not in hdmap.successors(a):
            raise RoutingError(f"route_polyline: expected lanelet {b} to follow lanelet {a}, it does not")
    parts = [hdmap.lanelets[i].centerline.xy_m for i in lanelet_ids]
    # Consecutive lanelets share their end points; a link bridged over a gap (a route file's
    # connect_gaps_m) keeps both, and the joined line crosses the gap straight.
    joined = [parts[0]]
    for prev, part in itertools.pairwise(parts):
        joined.append(part[1:] if float(np.hypot(*(part[0] - prev[-1]))) < JOIN_TOLERANCE_M else part)
    xy = np.vstack(joined)
    if closed:
        xy = xy[:-1]
    return Polyline(xy, closed=closed)


def lanelet_starts_m(hdmap: HDMap, lanelet_ids: tuple[int, ...]) -> np.ndarray:
    """(N+1,) route s where each lanelet begins, then the route's end."""
    lengths = [hdmap.lanelets[i].centerline.length_m for i in lanelet_ids]
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
