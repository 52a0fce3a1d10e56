"""aUToronto's lattice over the route and its sibling lanelets (7.1.3), built once per map.

Stations lie every ``station_spacing_m`` along the route. At each the lattice has a node on the route
lane's centre line and on the centre line of each lanelet beside it, found on the map:

- a **sibling**: a lanelet beside the route's, in its direction, that Lanelet2 lets a lane change enter
  (``HDMap.neighbours``: the line between them may be crossed). Bus bays are left out: they are
  places to stop, not lanes to drive by;
- the **opposite** lane: the lanelet on the left running the other way. Its nodes are usable only
  while decision's pass rule allows a pass (the opposite lane clear; ``decision.pass_rule``).

Each node is a lateral state (d, d', d'') in the route's Frenet frame, d left positive; lane centre
lines run parallel to the route, so d' = d'' = 0 there. Edges join a node to nodes 1 to
``max_span_stations`` stations ahead (a lane keep spans one station, a lane change as many as its
comfort needs) by a quintic Hermite spline d(s) matching position, slope and curvature at both ends:
the path's position, heading and curvature are continuous through every node. Edges whose curvature
the steering cannot follow, or whose body (rear axle on the path, body along its tangent) would
leave the map's drivable area, are not in the lattice (aUToronto's curvature and curb constraints).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from lastmile.core.geometry import FloatArray
from lastmile.core.polyline import Polyline
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.model import DRIVABLE_SUBTYPES
from lastmile.planning.lattice_config import LatticeConfig
from lastmile.planning.road_edge import DrivableLookup

SAMPLE_M = 1.0
"""Along-route spacing of the samples an edge is checked at against tracks."""
ROAD_SAMPLE_M = 2.0
"""... and against the road surface when the lattice is built (the body is 4-5 m long, so its corners
sweep every part of the road it covers at this spacing; the exact edge test of the map costs ~10 us a
point, and the campus lattice has ~1,000 edges that leave the route lane)."""


class LaneKind(IntEnum):
    """Which lane a node lies on."""

    OWN = 0
    SIBLING = 1
    OPPOSITE = 2


@dataclass(frozen=True, slots=True)
class LatticeNode:
    """A lattice node: lateral offset (rear axle) on a lane's centre line at a station."""

    d_m: float
    kind: LaneKind
    lanelet_id: int


@dataclass(frozen=True, slots=True)
class LatticeEdge:
    """An edge from a node to ``to_slot`` at the station ``span`` ahead.

    Attributes:
        length_m: the path's length along the edge.
        peak_curvature_1pm: its largest |d''| (the lateral curvature it adds to the route's).
    """

    to_slot: int
    span: int
    length_m: float
    peak_curvature_1pm: float


@dataclass(frozen=True, slots=True)
class Hermite5:
    """A quintic d(s) on [s0, s0 + length] (coefficients in u = (s - s0) / length, lowest first)."""

    s0_m: float
    length_m: float
    coef: tuple[float, float, float, float, float, float]

    @classmethod
    def between(
        cls, s0_m: float, s1_m: float, start: tuple[float, float, float], end: tuple[float, float, float]
    ) -> Hermite5:
        """The quintic from (d, d', d'') = ``start`` at ``s0_m`` to ``end`` at ``s1_m``."""
        length = s1_m - s0_m
        d0, v0, a0 = start[0], start[1] * length, start[2] * length * length
        d1, v1, a1 = end[0], end[1] * length, end[2] * length * length
        dd = d1 - d0
        c3 = 10.0 * dd - 6.0 * v0 - 4.0 * v1 - 1.5 * a0 + 0.5 * a1
        c4 = -15.0 * dd + 8.0 * v0 + 7.0 * v1 + 1.5 * a0 - a1
        c5 = 6.0 * dd - 3.0 * v0 - 3.0 * v1 - 0.5 * a0 + 0.5 * a1
        return cls(s0_m, length, (d0, v0, 0.5 * a0, c3, c4, c5))

    def state(self, s_m: FloatArray, order: int = 0) -> FloatArray:
        """d (order 0), d' (1) or d'' (2) at route s (clamped to the edge)."""
        u = np.clip((np.asarray(s_m, dtype=float) - self.s0_m) / self.length_m, 0.0, 1.0)
        c = list(self.coef)
        for _ in range(order):
            c = [i * c[i] for i in range(1, len(c))]
        out = np.full(u.shape, c[-1])
        for coefficient in reversed(c[:-1]):  # Horner
            out = out * u + coefficient
        return np.asarray(out / self.length_m**order, dtype=float)

    def samples_m(self, step_m: float = SAMPLE_M) -> FloatArray:
        n = max(2, math.ceil(self.length_m / step_m) + 1)
        return np.linspace(self.s0_m, self.s0_m + self.length_m, n)

    def peak_curvature_1pm(self) -> float:
        return float(np.abs(self.state(self.samples_m(), 2)).max())

    def path_length_m(self) -> float:
        s = self.samples_m()
        return float(np.hypot(np.diff(s), np.diff(self.state(s))).sum())


def body_corners_sd(
    s_m: FloatArray, d_m: FloatArray, slope: FloatArray, behind_m: float, ahead_m: float, half_width_m: float
) -> FloatArray:
    """(N, 4, 2) corners in route (s, d) of a body whose rear axle is at (s, d), along the path's tangent."""
    psi = np.arctan(slope)
    cos, sin = np.cos(psi)[:, None], np.sin(psi)[:, None]
    along = np.array([-behind_m, -behind_m, ahead_m, ahead_m])
    side = np.array([-half_width_m, half_width_m, -half_width_m, half_width_m])
    cs = s_m[:, None] + along[None, :] * cos - side[None, :] * sin
    cd = d_m[:, None] + along[None, :] * sin + side[None, :] * cos
    return np.stack([cs, cd], axis=-1)


def route_sd_to_xy(route: Polyline, sd: FloatArray) -> FloatArray:
    """(N, 2) route (s, d) -> map (x, y)."""
    base = route.points_at(sd[:, 0])
    tangent = route.points_at(sd[:, 0] + 0.5) - route.points_at(sd[:, 0] - 0.5)
    heading = np.arctan2(tangent[:, 1], tangent[:, 0])
    return np.asarray(base + sd[:, 1:2] * np.c_[-np.sin(heading), np.cos(heading)], dtype=float)


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleBody:
    """The body's extent about the rear axle, and the curvature its steering follows."""

    behind_m: float
    ahead_m: float
    half_width_m: float
    max_curvature_1pm: float


class LatticeGraph:
    """The route's lattice: nodes per station, edges per node (pre-generated, checked against the road).

    Station k (an unwrapped index; on a loop station k is station k mod ``n_stations``) lies at route
    s = k x ``spacing_m``. Nodes are addressed (k, slot); slot 0 is always the route lane.
    """

    def __init__(
        self,
        layers: SLayerDatabase | None,
        route: Polyline,
        body: VehicleBody,
        config: LatticeConfig,
        drivable: DrivableLookup | None = None,
        curvature_share: float = 0.8,
    ) -> None:
        self.route, self.body, self.config = route, body, config
        length = route.length_m
        if route.closed:
            self.n_stations = max(1, round(length / config.station_spacing_m))
            self.spacing_m = length / self.n_stations
        else:
            self.spacing_m = config.station_spacing_m
            self.n_stations = int(length // self.spacing_m) + 1
        self.curvature_limit_1pm = curvature_share * body.max_curvature_1pm
        self.nodes: list[tuple[LatticeNode, ...]] = [
            self._station_nodes(layers, k * self.spacing_m) for k in range(self.n_stations)
        ]
        self.edges: list[tuple[tuple[LatticeEdge, ...], ...]] = self._build_edges(drivable)

    # --- nodes ----------------------------------------------------------------------------------------
    def _station_nodes(self, layers: SLayerDatabase | None, s_m: float) -> tuple[LatticeNode, ...]:
        own_id = (
            -1
            if layers is None or not len(layers.lanelet_id)
            else int(layers.lanelet_id[layers.record_index(s_m)])
        )
        nodes = [LatticeNode(0.0, LaneKind.OWN, own_id)]
        if layers is None:
            return tuple(nodes)
        i = layers.record_index(s_m)
        hd = layers.hdmap
        x, y, heading = self.route.point_at(s_m)
        nx, ny = -math.sin(heading), math.cos(heading)
        siblings = set(hd.neighbours(own_id))
        for probe_d in (
            float(layers.lane_left_d_m[i]) + self.config.probe_m,
            float(layers.lane_right_d_m[i]) - self.config.probe_m,
        ):
            px, py = x + probe_d * nx, y + probe_d * ny
            lid = hd.lanelet_at(px, py)
            if lid is None or lid == own_id:
                continue
            ll = hd.lanelets[lid]
            if ll.subtype not in DRIVABLE_SUBTYPES or ll.bus_stop_id:
                continue
            at = ll.centerline.project(px, py)
            cos = math.cos(ll.centerline.heading_at(at.s_m) - heading)
            cx, cy, _ = ll.centerline.point_at(at.s_m)
            d = (cx - x) * nx + (cy - y) * ny
            if cos >= self.config.parallel_cos and lid in siblings:
                nodes.append(LatticeNode(d, LaneKind.SIBLING, lid))
            elif cos <= -self.config.parallel_cos and probe_d > 0.0:
                nodes.append(LatticeNode(d, LaneKind.OPPOSITE, lid))
        return tuple(nodes)

    # --- edges ----------------------------------------------------------------------------------------
    def node(self, k: int, slot: int) -> LatticeNode:
        return self.nodes[self.wrap(k)][slot]

    def wrap(self, k: int) -> int:
        return k % self.n_stations if self.route.closed else k

    def station_s_m(self, k: int) -> float:
        return k * self.spacing_m

    def exists(self, k: int) -> bool:
        return self.route.closed or 0 <= k < self.n_stations

    def edge_curve(self, k: int, slot: int, edge: LatticeEdge) -> Hermite5:
        """The edge's d(s), in the unwrapped s of station k."""
        d0 = self.node(k, slot).d_m
        d1 = self.node(k + edge.span, edge.to_slot).d_m
        return Hermite5.between(
            self.station_s_m(k), self.station_s_m(k + edge.span), (d0, 0.0, 0.0), (d1, 0.0, 0.0)
        )

    def _build_edges(self, drivable: DrivableLookup | None) -> list[tuple[tuple[LatticeEdge, ...], ...]]:
        proposals: list[tuple[int, int, LatticeEdge, Hermite5]] = []
        for k in range(self.n_stations):
            for slot, node in enumerate(self.nodes[k]):
                for span in range(1, self.config.max_span_stations + 1):
                    if not self.exists(k + span):
                        break
                    for to_slot, to in enumerate(self.nodes[self.wrap(k + span)]):
                        same_lane = to.kind == node.kind and abs(to.d_m - node.d_m) < 1.0
                        if same_lane and span != 1:
                            continue  # a lane keep spans one station
                        curve = Hermite5.between(
                            self.station_s_m(k), self.station_s_m(k + span), (node.d_m, 0, 0), (to.d_m, 0, 0)
                        )
                        kappa = curve.peak_curvature_1pm()
                        if kappa > self.curvature_limit_1pm:
                            continue
                        edge = LatticeEdge(to_slot, span, curve.path_length_m(), kappa)
                        proposals.append((k, slot, edge, curve))
        keep = self._on_road(
            [(c, self.keeps_route_lane(k, slot, e)) for k, slot, e, c in proposals], drivable
        )
        table: list[list[list[LatticeEdge]]] = [[[] for _ in st] for st in self.nodes]
        for (k, slot, edge, _), ok in zip(proposals, keep, strict=True):
            if ok:
                table[k][slot].append(edge)
        return [tuple(tuple(es) for es in st) for st in table]

    def keeps_route_lane(self, k: int, slot: int, edge: LatticeEdge) -> bool:
        """Whether an edge keeps to the route lane at both ends."""
        return (
            self.node(k, slot).kind == LaneKind.OWN
            and self.node(k + edge.span, edge.to_slot).kind == LaneKind.OWN
        )

    def _on_road(self, curves: list[tuple[Hermite5, bool]], drivable: DrivableLookup | None) -> list[bool]:
        """Which edges keep every body corner on the drivable area (route-lane keeps: the route's own
        road, not checked here; the pull-over machinery keeps the body off its kerbs)."""
        if drivable is None:
            return [True] * len(curves)
        b = self.body
        chunks, owners = [], []
        for i, (curve, own) in enumerate(curves):
            if own:
                continue
            s = curve.samples_m(ROAD_SAMPLE_M)
            corners = body_corners_sd(
                s, curve.state(s), curve.state(s, 1), b.behind_m, b.ahead_m, b.half_width_m
            )
            chunks.append(corners.reshape(-1, 2))
            owners.append(np.full(len(chunks[-1]), i))
        ok = np.ones(len(curves), dtype=bool)
        if chunks:
            inside = drivable(route_sd_to_xy(self.route, np.vstack(chunks)))
            bad = np.unique(np.concatenate(owners)[~np.asarray(inside, dtype=bool)])
            ok[bad] = False
        return ok.tolist()
