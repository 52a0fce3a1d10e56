"""A* over aUToronto's lattice (7.1.3), with BFS-limited obstacle pruning.

Each planning cycle the search runs from the shuttle's planned lateral state (d, d', d'') at its rear
axle to any node ``horizon_m`` ahead. The first edges leave that state for the nodes one to
``max_span_stations + 1`` stations ahead (quintics again, so the path stays curvature-continuous
with the one being driven); from there the lattice's own edges follow. The cost of an edge is

    w_length x length + w_lane_change x [lane change] + w_deviation x (metres off the route lane)
    + w_lateral_accel x peak lateral acceleration at the passing speed + w_obstacle / least clearance

and the heuristic is the remaining distance along the route (never more than the length left, so
the first path reaching the goal is the cheapest). Obstacles prune edges: only edges within
``prune_depth`` edges of the shuttle, found by a breadth-first search from its start, are checked
(aUToronto: checking every edge online is too slow); the rest are searched unchecked, and the next
cycles check them as the shuttle comes near. An edge is pruned when the body along it comes closer
than ``clearance_m`` to a standing track or ``min_clearance_m`` to a moving one (constant velocity,
timed at the passing speed). A route-lane keep is pruned only when a standing obstacle leaves no room
in the lane for the body with the potential field's clearance (that nudge drives it); road users moving
in the route lane are followed by decision, not planned around. No path: a full blockage, and the
search reports where the first obstacle that pruned an edge begins.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.geometry import FloatArray
from lastmile.planning.lattice_graph import (
    ROAD_SAMPLE_M,
    Hermite5,
    LaneKind,
    LatticeEdge,
    LatticeGraph,
    body_corners_sd,
    route_sd_to_xy,
)
from lastmile.planning.road_edge import DrivableLookup

CLEARANCE_CAP_M = 3.0
"""Clearances beyond this add no cost (the track is not beside the edge in any sense that matters)."""
MOVING_MPS = 0.5
"""Tracks faster than this are predicted at constant velocity; slower ones stand (the pass rule's)."""
LANE_CHANGE_D_M = 1.0
"""Two lateral states further apart than this lie in different lanes."""

SHAPE_CACHE = 4096
"""Body envelopes of lattice edges kept (a few hundred distinct shapes on a map: lane widths and spans)."""

Node = tuple[int, int]
"""(unwrapped station index, slot)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SearchObstacle:
    """A track in the search's unwrapped route frame: centre (s, d), extent, velocity along and across."""

    s_m: float
    d_m: float
    length_m: float
    width_m: float
    v_s_mps: float = 0.0
    v_d_mps: float = 0.0

    @property
    def moving(self) -> bool:
        return math.hypot(self.v_s_mps, self.v_d_mps) > MOVING_MPS

    @property
    def rear_s_m(self) -> float:
        return self.s_m - self.length_m / 2.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SearchRequest:
    """One cycle's search.

    Attributes:
        ego_s_m: the rear axle's route s (the lap the station indices are counted in).
        start: the planned (d, d', d'') at the rear axle.
        allow_opposite: decision's pass rule allows the opposite lane (it is clear).
        obstacles: tracks near the route, in the same s lap.
        speed_mps: the speed moving tracks are timed at.
        clearance_m, min_clearance_m: the body's gap to a standing track / a moving one.
        in_lane_clearance_m: the potential field's clearance, for the route lane's keeps.
        lane_half_width_m: the route lane's half width.
        return_gap_m: the body's rear clears a standing track's front (and its front the track's
            rear) by this before the clearance beside it no longer applies.
    """

    ego_s_m: float
    start: tuple[float, float, float]
    allow_opposite: bool
    obstacles: tuple[SearchObstacle, ...]
    speed_mps: float
    clearance_m: float
    min_clearance_m: float
    in_lane_clearance_m: float
    lane_half_width_m: float
    return_gap_m: float = 1.0


@dataclass(frozen=True, slots=True)
class TrackArrays:
    """A cycle's tracks as arrays (one NumPy pass per edge checks them all).

    Standing tracks are kept clear lengthwise too: their half length carries ``return_gap_m`` (the
    body comes back only that far past them, the offset-pass planner's rule), and their velocity is
    taken as zero.
    """

    s_m: FloatArray
    d_m: FloatArray
    half_length_m: FloatArray
    half_width_m: FloatArray
    v_s_mps: FloatArray
    v_d_mps: FloatArray
    moving: np.ndarray
    rear_s_m: FloatArray

    @classmethod
    def of(cls, req: SearchRequest) -> TrackArrays:
        obs = req.obstacles
        moving = np.array([o.moving for o in obs], dtype=bool)
        col = np.array(
            [(o.s_m, o.d_m, o.length_m / 2.0, o.width_m / 2.0, o.v_s_mps, o.v_d_mps) for o in obs],
            dtype=float,
        ).reshape(-1, 6)
        v_s, v_d = np.where(moving, col[:, 4], 0.0), np.where(moving, col[:, 5], 0.0)
        half_l = col[:, 2] + np.where(moving, 0.0, req.return_gap_m)
        return cls(col[:, 0], col[:, 1], half_l, col[:, 3], v_s, v_d, moving, col[:, 0] - col[:, 2])


@dataclass(frozen=True, slots=True)
class LatticePath:
    """The chosen chain of quintics and the lane of each one's end node."""

    curves: tuple[Hermite5, ...]
    kinds: tuple[LaneKind, ...]
    cost: float

    def d_at(self, s_m: FloatArray) -> FloatArray:
        """d(s) along the path (before its start: its first value; beyond its end: its last)."""
        s = np.asarray(s_m, dtype=float)
        out = np.full(
            s.shape, self.curves[-1].state(np.array([self.curves[-1].s0_m + self.curves[-1].length_m]))[0]
        )
        for curve in reversed(self.curves):
            inside = s <= curve.s0_m + curve.length_m
            out[inside] = curve.state(s[inside])
        return out

    def state_at(self, s_m: float) -> tuple[float, float, float] | None:
        """(d, d', d'') at route s, or None outside the path."""
        for curve in self.curves:
            if curve.s0_m <= s_m <= curve.s0_m + curve.length_m:
                at = np.array([s_m])
                return float(curve.state(at)[0]), float(curve.state(at, 1)[0]), float(curve.state(at, 2)[0])
        return None

    @property
    def leaves_route_lane(self) -> bool:
        return any(k != LaneKind.OWN for k in self.kinds)


@dataclass(slots=True)
class SearchResult:
    """The path found (None: a full blockage), where the blocking obstacle begins, and the work done."""

    path: LatticePath | None
    blocked_at_s_m: float | None = None
    checked_edges: int = 0
    expanded: int = 0
    pruned_edges: int = 0
    hits: list[float] = field(default_factory=list)


class LatticeSearch:
    """A* over a :class:`LatticeGraph` with the paper's costs and BFS-limited pruning."""

    def __init__(self, graph: LatticeGraph, drivable: DrivableLookup | None = None) -> None:
        self.graph = graph
        self.drivable = drivable
        self._tracks: TrackArrays | None = None
        self._shapes: dict[tuple[float, ...], tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = {}

    def search(self, req: SearchRequest) -> SearchResult:
        g, c = self.graph, self.graph.config
        k0 = math.floor(req.ego_s_m / g.spacing_m + 1e-9)
        k_goal = math.ceil((req.ego_s_m + c.horizon_m) / g.spacing_m)
        if not g.route.closed:
            k_goal = min(k_goal, g.n_stations - 1)
        result = SearchResult(path=None)
        self._tracks = TrackArrays.of(req)
        if k_goal <= k0:
            return result
        first = self._start_edges(req, k0, k_goal)
        depth = self._bfs_depth([n for n, _ in first], req)
        start_kind = LaneKind.OWN if abs(req.start[0]) < LANE_CHANGE_D_M else LaneKind.OPPOSITE
        begun = start_kind != LaneKind.OWN  # out of the lane: the first edges continue a begun move
        best: dict[Node, float] = {}
        came: dict[Node, tuple[Node | None, Hermite5]] = {}
        heap: list[tuple[float, float, Node, bool]] = []
        for node, curve in first:
            cost = self._edge_cost(req, curve, start_kind, g.node(*node).kind, True, result, first=begun)
            if math.isfinite(cost) and cost < best.get(node, math.inf):
                best[node] = cost
                came[node] = (None, curve)
                heapq.heappush(heap, (cost + self._h(node, k_goal), cost, node, False))
        while heap:
            _, cost, node, charged = heapq.heappop(heap)
            if not charged and cost > best.get(node, math.inf):
                continue
            result.expanded += 1
            if node[0] >= k_goal:
                if charged or g.node(*node).kind == LaneKind.OWN:
                    result.path = self._path(node, came, cost)
                    return result
                # Ending off the route lane leaves a lane change back and the stretch before it.
                back = cost + c.w_lane_change + c.w_deviation * c.horizon_m
                heapq.heappush(heap, (back, back, node, True))
                continue
            k, slot = node
            for edge in g.edges[g.wrap(k)][slot]:
                nxt = (k + edge.span, edge.to_slot)
                if not self._allowed(nxt, req):
                    continue
                curve = g.edge_curve(k, slot, edge)
                checked = depth.get(node, c.prune_depth) < c.prune_depth
                step = self._edge_cost(
                    req, curve, g.node(k, slot).kind, g.node(*nxt).kind, checked, result, edge
                )
                total = cost + step
                if total < best.get(nxt, math.inf):
                    best[nxt] = total
                    came[nxt] = (node, curve)
                    heapq.heappush(heap, (total + self._h(nxt, k_goal), total, nxt, False))
        result.blocked_at_s_m = min(result.hits) if result.hits else None
        return result

    # --- the graph around the shuttle ---------------------------------------------------------------
    def _allowed(self, node: Node, req: SearchRequest) -> bool:
        if not self.graph.exists(node[0]):
            return False
        return req.allow_opposite or self.graph.node(*node).kind != LaneKind.OPPOSITE

    def _start_edges(self, req: SearchRequest, k0: int, k_goal: int) -> list[tuple[Node, Hermite5]]:
        """Quintics from the planned state at the rear axle to the nodes of the next stations."""
        g = self.graph
        out = []
        for k in range(k0 + 1, min(k0 + g.config.max_span_stations + 1, k_goal) + 1):
            if not g.exists(k):
                break
            s_k = g.station_s_m(k)
            if s_k - req.ego_s_m < 1.0:
                continue
            for slot, node in enumerate(g.nodes[g.wrap(k)]):
                if not self._allowed((k, slot), req):
                    continue
                keep = abs(node.d_m - req.start[0]) < LANE_CHANGE_D_M
                curve = Hermite5.between(req.ego_s_m, s_k, req.start, (node.d_m, 0.0, 0.0))
                if curve.peak_curvature_1pm() > g.curvature_limit_1pm:
                    continue
                if not (keep and node.kind == LaneKind.OWN) and not self._on_road(curve):
                    continue
                out.append(((k, slot), curve))
        return out

    def _on_road(self, curve: Hermite5) -> bool:
        if self.drivable is None:
            return True
        b = self.graph.body
        s = curve.samples_m(ROAD_SAMPLE_M)
        corners = body_corners_sd(s, curve.state(s), curve.state(s, 1), b.behind_m, b.ahead_m, b.half_width_m)
        return bool(np.all(self.drivable(route_sd_to_xy(self.graph.route, corners.reshape(-1, 2)))))

    def _bfs_depth(self, starts: list[Node], req: SearchRequest) -> dict[Node, int]:
        """Edges from the start (depth 0 is the start's own edges) to each node, up to prune_depth."""
        g, limit = self.graph, self.graph.config.prune_depth
        depth = dict.fromkeys(starts, 1)
        queue = deque(starts)
        while queue:
            node = queue.popleft()
            if depth[node] >= limit:
                continue
            for edge in g.edges[g.wrap(node[0])][node[1]]:
                nxt = (node[0] + edge.span, edge.to_slot)
                if nxt not in depth and self._allowed(nxt, req):
                    depth[nxt] = depth[node] + 1
                    queue.append(nxt)
        return depth

    def _h(self, node: Node, k_goal: int) -> float:
        return self.graph.config.w_length * max(
            0.0, self.graph.station_s_m(k_goal) - self.graph.station_s_m(node[0])
        )

    # --- costs ----------------------------------------------------------------------------------------
    def _edge_cost(
        self,
        req: SearchRequest,
        curve: Hermite5,
        from_kind: LaneKind,
        to_kind: LaneKind,
        checked: bool,
        result: SearchResult,
        edge: LatticeEdge | None = None,
        first: bool = False,
    ) -> float:
        c = self.graph.config
        length = edge.length_m if edge is not None else curve.path_length_m()
        kappa = edge.peak_curvature_1pm if edge is not None else curve.peak_curvature_1pm()
        change = abs(sum(curve.coef) - curve.coef[0]) >= LANE_CHANGE_D_M  # d(end) - d(start)
        off = ((from_kind != LaneKind.OWN) + (to_kind != LaneKind.OWN)) / 2.0
        cost = (
            c.w_length * length
            + c.w_lane_change * change
            + c.w_deviation * curve.length_m * off
            + c.w_lateral_accel * req.speed_mps**2 * kappa
        )
        if not checked:
            return cost
        result.checked_edges += 1
        keep = from_kind == LaneKind.OWN and to_kind == LaneKind.OWN and not change
        clearance = self._clearance_m(req, curve, keep, result, first)
        if clearance is None:
            result.pruned_edges += 1
            return math.inf
        return cost + (c.w_obstacle / max(clearance, 0.05) if clearance < CLEARANCE_CAP_M else 0.0)

    def _clearance_m(
        self,
        req: SearchRequest,
        curve: Hermite5,
        route_lane_keep: bool,
        result: SearchResult,
        first: bool = False,
    ) -> float | None:
        """The least gap from the body along the edge to the tracks beside it (None: pruned).

        A new move keeps ``clearance_m`` from standing tracks (what decision's pass rule checked); once
        the shuttle is out of its lane, the first edge, which continues the move being driven, is
        pruned only inside ``min_clearance_m``:
        a radar track of a car being passed creeps 0.2-0.3 m towards the shuttle as it sees the car's
        side, and re-planning must not turn a begun pass into a blockage beside the car."""
        b = self.graph.body
        s = curve.samples_m()
        if route_lane_keep:
            return self._in_lane_clearance_m(req, float(s[0]) - b.behind_m, float(s[-1]) + b.ahead_m, result)
        lo_s, hi_s, lo_d, hi_d = self._envelope(curve, s)
        t_s = np.maximum(s - req.ego_s_m, 0.0) / max(req.speed_mps, 0.5)
        tracks = self._tracks
        if tracks is None or not len(tracks.s_m):
            return math.inf
        # (tracks, samples): each track where it will be when the shuttle is at each sample.
        centre_s = tracks.s_m[:, None] + tracks.v_s_mps[:, None] * t_s[None, :]
        centre_d = tracks.d_m[:, None] + tracks.v_d_mps[:, None] * t_s[None, :]
        half_l, half_w = tracks.half_length_m[:, None], tracks.half_width_m[:, None]
        gap_s = np.maximum(centre_s - half_l - hi_s[None, :], lo_s[None, :] - centre_s - half_l)
        gap_d = np.maximum(centre_d - half_w - hi_d[None, :], lo_d[None, :] - centre_d - half_w)
        gap = np.where(gap_s < 0.0, gap_d, np.inf).min(axis=1)
        need = np.where(tracks.moving | first, req.min_clearance_m, req.clearance_m)
        too_close = np.flatnonzero(gap < need - 0.05)
        if len(too_close):
            result.hits.append(float(tracks.rear_s_m[too_close].min()))
            return None
        return float(gap.min())

    def _envelope(
        self, curve: Hermite5, s_m: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The body's extent (s from, s to, d from, d to) at each sample; lattice edges repeat every
        cycle (a lap apart on a loop), so their shape is kept, keyed by lateral ends and length."""
        key = (
            round(curve.coef[0], 6),
            round(sum(curve.coef), 6),
            round(curve.length_m, 6),
            curve.coef[1],
            curve.coef[2],
        )
        shape = self._shapes.get(key)
        if shape is None:
            b = self.graph.body
            corners = body_corners_sd(
                s_m - curve.s0_m, curve.state(s_m), curve.state(s_m, 1), b.behind_m, b.ahead_m, b.half_width_m
            )
            shape = (
                corners[..., 0].min(axis=1),
                corners[..., 0].max(axis=1),
                corners[..., 1].min(axis=1),
                corners[..., 1].max(axis=1),
            )
            if curve.coef[1] == 0.0 and curve.coef[2] == 0.0 and len(self._shapes) < SHAPE_CACHE:
                self._shapes[key] = shape
        return shape[0] + curve.s0_m, shape[1] + curve.s0_m, shape[2], shape[3]

    def _in_lane_clearance_m(
        self, req: SearchRequest, lo_s_m: float, hi_s_m: float, result: SearchResult
    ) -> float | None:
        """A route-lane keep: pruned only when a standing obstacle leaves the body no room in the lane.

        The lane is driven by the potential field: it moves the body clear of an obstacle by its
        clearance when the lane has room for that, and otherwise keeps the centre, where decision's
        in-path test lets the shuttle by an obstacle ``min_clearance_m`` from its body. The keep is
        pruned only when neither holds (the rule the default planner and decision apply together).
        """
        b, c = self.graph.body, self.graph.config
        edge_l = req.lane_half_width_m - c.lane_margin_m
        least = math.inf
        for o in req.obstacles:
            if o.moving or o.s_m + o.length_m / 2.0 < lo_s_m or o.rear_s_m > hi_s_m:
                continue
            o_lo, o_hi = o.d_m - o.width_m / 2.0, o.d_m + o.width_m / 2.0
            room_left = edge_l - (o_hi + req.in_lane_clearance_m)
            room_right = (o_lo - req.in_lane_clearance_m) + edge_l
            nudged = max(room_left, room_right) >= 2.0 * b.half_width_m
            centred = max(o_lo - b.half_width_m, -b.half_width_m - o_hi)
            if not nudged and centred < req.min_clearance_m - 0.05:
                result.hits.append(o.rear_s_m)
                return None
            least = min(least, max(centred, req.in_lane_clearance_m) if nudged else centred)
        return least

    def _path(self, node: Node, came: dict[Node, tuple[Node | None, Hermite5]], cost: float) -> LatticePath:
        curves, kinds = [], []
        at: Node | None = node
        while at is not None:
            prev, curve = came[at]
            curves.append(curve)
            kinds.append(self.graph.node(*at).kind)
            at = prev
        return LatticePath(tuple(reversed(curves)), tuple(reversed(kinds)), cost)
