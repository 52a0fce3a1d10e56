"""Generates the example town: a Lanelet2 map of a city block with real junctions
(``python -m lastmile.hdmap.town examples/maps/town/town.osm``).

The Lanelet2 example map offers one closed circuit (its roundabout) and the campus one ring, so neither
shows a service through several junctions of different kinds. The town is a block of four streets with
the features a surveyed map of a shuttle route has, written the way such maps write them:

- Main Street (south, two-way) meets West Avenue at an **all-way stop** whose rule lists its four
  approach lanelets and stop lines, while the lanelets do not reference the rule (as on real maps where
  it was drawn from the rule's side), and meets East Avenue at a **signalised** junction (a rule per
  approach, two phases).
- North Street is **one way with two lanes**; it leaves West Avenue at a second all-way stop (a T,
  its lanelets referencing the rule, the usual way) and joins East Avenue at a **give-way** line (a
  ``right_of_way`` rule: North Street yields to the avenue). Two all-way stops on one map: each
  has its own arrival order.
- Every junction has lanelets for each allowed movement, tagged ``turn_direction``; they carry no speed
  limit (the route file's limit applies there), the streets 30 km/h.
- Mid-block zebra crossings on Main and North Street, curbstones along every street, light poles and two
  buildings (landmarks), streets running on past the block to the map's edge.
"""

from __future__ import annotations

import itertools
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lanelet2.core as ll2
import numpy as np
from lanelet2.io import Origin, write
from lanelet2.projection import UtmProjector

from lastmile.core.geometry import FloatArray
from lastmile.hdmap.osm_builder import OsmBuilder

ORIGIN_LAT_DEG, ORIGIN_LON_DEG = 43.4650, -80.5300  # somewhere in Waterloo, Ontario; the town is made up
LW = 3.5  # lane width, m
JUNCTION_HALF_M = 10.0  # streets stop this far from a junction's centre; its movements fill the box
STREET_LIMIT_KMH = 30
MAX_LANELET_M = 40.0  # streets are cut into lanelets at most this long, as surveyed maps are
CURVE_POINTS = 13
HEAD_W_M, HEAD_H_M, HEAD_Z_M = 0.35, 1.0, 4.6  # a 300 mm three-lens head; MUTCD's 4.6 m clearance
POLE_SPACING_M, POLE_OFFSET_M, POLE_HEIGHT_M = 40.0, 2.0, 8.0  # behind the curb
CROSSWALK_W_M = 4.0

# Junction centres (x, y), m.
A, B, C, D = (0.0, 0.0), (200.0, 0.0), (0.0, 120.0), (200.0, 120.0)


@dataclass(frozen=True, slots=True)
class LaneEnd:
    """Where a street lane meets a junction: its bounds' end (or start) points and its heading."""

    left_xy: tuple[float, float]
    right_xy: tuple[float, float]
    heading_rad: float
    lanelet: Any
    rank: int  # 0 is the rightmost lane of its direction


@dataclass
class Junction:
    centre: tuple[float, float]
    entries: list[LaneEnd] = field(default_factory=list)
    exits: list[LaneEnd] = field(default_factory=list)
    movements: dict[tuple[int, int], Any] = field(default_factory=dict)  # (entry, exit) -> lanelet


def build_town_map() -> Any:
    """The town as a ``lanelet2.core.LaneletMap`` in local metres (x east, y north)."""
    b = OsmBuilder()
    junctions = {name: Junction(xy) for name, xy in (("A", A), ("B", B), ("C", C), ("D", D))}
    _street(b, junctions, (-70.0, 0.0), (270.0, 0.0), two_way=True)  # Main Street
    _street(b, junctions, (0.0, -70.0), (0.0, 190.0), two_way=True)  # West Avenue
    _street(b, junctions, (200.0, -70.0), (200.0, 190.0), two_way=True)  # East Avenue
    _street(b, junctions, (0.0, 120.0), (200.0, 120.0), two_way=False)  # North Street, one way east
    for junction in junctions.values():
        _movements(b, junction)
    _all_way_stop(b, junctions["A"], "Main St / West Ave", referenced=False)
    _all_way_stop(b, junctions["C"], "North St / West Ave", referenced=True)
    _signals(b, junctions["B"])
    _give_way(b, junctions["D"])
    _crosswalk(b, (100.0, 0.0), 0.0)
    _crosswalk(b, (100.0, 120.0), 0.0)
    for corners, name in (
        ([(25.0, 25.0), (85.0, 25.0), (85.0, 95.0), (25.0, 95.0)], "Library"),
        ([(120.0, 25.0), (175.0, 25.0), (175.0, 95.0), (120.0, 95.0)], "Clinic"),
    ):
        b.area(corners, "building", "wall", name=name, height="12")
    _poles(b)
    return b.map


def _street(
    b: OsmBuilder,
    junctions: dict[str, Junction],
    p: tuple[float, float],
    q: tuple[float, float],
    two_way: bool,
) -> None:
    """A straight street from ``p`` to ``q`` cut at every junction on its axis.

    Two-way: a lane each way sharing a dashed centre line. One-way: two lanes along p -> q sharing a
    dashed divider. Curbstones on both edges.
    """
    axis = _Axis(p, q)
    on_axis = sorted(
        ((along, j) for j in junctions.values() if (along := axis.along_if_on(j.centre)) is not None),
        key=lambda aj: aj[0],
    )
    # Open stretches between junction boxes: (start, end, junction at start, junction at end).
    stretches: list[tuple[float, float, Junction | None, Junction | None]] = []
    start, start_j = 0.0, None
    for along, junction in on_axis:
        if along - JUNCTION_HALF_M - start > 1.0:
            stretches.append((start, along - JUNCTION_HALF_M, start_j, junction))
        start, start_j = along + JUNCTION_HALF_M, junction
    if axis.length_m - start > 1.0:
        stretches.append((start, axis.length_m, start_j, None))
    for s0, s1, j0, j1 in stretches:
        cuts = np.linspace(s0, s1, max(1, math.ceil((s1 - s0) / MAX_LANELET_M)) + 1).tolist()
        first: list[tuple[Any, int, int]] = []
        last: list[tuple[Any, int, int]] = []
        for a, c in itertools.pairwise(cuts):
            right = b.line(axis.segment(a, c, -LW), "curbstone", "high")
            mid = b.line(axis.segment(a, c, 0.0), "line_thin", "dashed")
            left = b.line(axis.segment(a, c, LW), "curbstone", "high")
            lanes = [(b.lanelet(mid, right, STREET_LIMIT_KMH), 0, +1)]
            if two_way:
                lanes.append((b.lanelet(mid.invert(), left.invert(), STREET_LIMIT_KMH), 0, -1))
            else:
                lanes.append((b.lanelet(left, mid, STREET_LIMIT_KMH), 1, +1))
            first = first or lanes
            last = lanes
        for lanelet, rank, sign in last:
            end = axis.lane_end(s1, lanelet, rank, sign, two_way)
            if j1 is not None:
                (j1.entries if sign > 0 else j1.exits).append(end)
        for lanelet, rank, sign in first:
            end = axis.lane_end(s0, lanelet, rank, sign, two_way)
            if j0 is not None:
                (j0.exits if sign > 0 else j0.entries).append(end)


class _Axis:
    """A street's straight axis: positions along it and offsets to its left."""

    def __init__(self, p: tuple[float, float], q: tuple[float, float]) -> None:
        self.p = np.asarray(p, dtype=float)
        d = np.asarray(q, dtype=float) - self.p
        self.length_m = float(np.hypot(*d))
        self.u = d / self.length_m
        self.n = np.array([-self.u[1], self.u[0]])
        self.heading_rad = math.atan2(self.u[1], self.u[0])

    def at(self, s_m: float, offset_m: float) -> tuple[float, float]:
        x, y = self.p + s_m * self.u + offset_m * self.n
        return float(x), float(y)

    def segment(self, s0_m: float, s1_m: float, offset_m: float) -> list[tuple[float, float]]:
        return [self.at(s0_m, offset_m), self.at(s1_m, offset_m)]

    def along_if_on(self, xy: tuple[float, float]) -> float | None:
        rel = np.asarray(xy, dtype=float) - self.p
        along = float(rel @ self.u)
        on = abs(float(rel @ self.n)) < 1e-6 and -1e-6 <= along <= self.length_m + 1e-6
        return along if on else None

    def lane_end(self, s_m: float, lanelet: Any, rank: int, sign: int, two_way: bool) -> LaneEnd:
        """The bounds' points of a lane where it meets a junction at ``s_m``."""
        if two_way:
            left, right = (0.0, -LW) if sign > 0 else (0.0, LW)
        else:
            left, right = (0.0, -LW) if rank == 0 else (LW, 0.0)
        return LaneEnd(
            left_xy=self.at(s_m, left),
            right_xy=self.at(s_m, right),
            heading_rad=self.heading_rad if sign > 0 else self.heading_rad + math.pi,
            lanelet=lanelet,
            rank=rank,
        )


def _turn(entry: LaneEnd, exit_: LaneEnd) -> str:
    bend = math.remainder(exit_.heading_rad - entry.heading_rad, 2 * math.pi)
    if abs(bend) < math.radians(30):
        return "straight"
    if abs(bend) > math.radians(150):
        return ""  # a U-turn: not a movement of these junctions
    return "left" if bend > 0 else "right"


def _movements(b: OsmBuilder, junction: Junction) -> None:
    """A lanelet for every movement: right turns from the rightmost lane into the rightmost, left turns
    from the leftmost into the leftmost, straight on lane to lane."""
    for i, entry in enumerate(junction.entries):
        for j, exit_ in enumerate(junction.exits):
            turn = _turn(entry, exit_)
            if not turn or np.hypot(*np.subtract(entry.left_xy, exit_.left_xy)) < 1.0:
                continue
            entry_lanes = max(e.rank for e in junction.entries if _same_road(e, entry)) + 1
            exit_lanes = max(e.rank for e in junction.exits if _same_road(e, exit_)) + 1
            if turn == "right" and (entry.rank, exit_.rank) != (0, 0):
                continue
            if turn == "left" and (entry.rank, exit_.rank) != (entry_lanes - 1, exit_lanes - 1):
                continue
            if turn == "straight" and entry.rank != exit_.rank:
                continue
            left = b.line(
                _curve(entry.left_xy, exit_.left_xy, entry.heading_rad, exit_.heading_rad), "virtual"
            )
            right_type = ("curbstone", "high") if turn == "right" else ("virtual", "")
            right = b.line(
                _curve(entry.right_xy, exit_.right_xy, entry.heading_rad, exit_.heading_rad), *right_type
            )
            junction.movements[(i, j)] = b.lanelet(left, right, None, turn_direction=turn)


def _same_road(a: LaneEnd, b_: LaneEnd) -> bool:
    return abs(math.remainder(a.heading_rad - b_.heading_rad, 2 * math.pi)) < 1e-6 and (
        abs(
            (b_.right_xy[0] - a.right_xy[0]) * math.cos(a.heading_rad)
            + (b_.right_xy[1] - a.right_xy[1]) * math.sin(a.heading_rad)
        )
        < 1e-6
    )


def _curve(p0: tuple[float, float], p1: tuple[float, float], h0: float, h1: float) -> FloatArray:
    """A cubic Bezier from ``p0`` heading ``h0`` to ``p1`` heading ``h1``: the usual circular-arc
    approximation (control arms (4/3) tan(turn/4) r), a straight line when the headings agree."""
    chord = float(np.hypot(p1[0] - p0[0], p1[1] - p0[1]))
    turn = abs(math.remainder(h1 - h0, 2 * math.pi))
    arm = (
        chord / 3.0 if turn < 1e-6 else (4.0 / 3.0) * math.tan(turn / 4.0) * chord / (2 * math.sin(turn / 2))
    )
    c0 = np.array(p0) + arm * np.array([math.cos(h0), math.sin(h0)])
    c1 = np.array(p1) - arm * np.array([math.cos(h1), math.sin(h1)])
    t = np.linspace(0.0, 1.0, CURVE_POINTS)[:, None]
    pts = (
        (1 - t) ** 3 * np.array(p0)
        + 3 * (1 - t) ** 2 * t * c0
        + 3 * (1 - t) * t**2 * c1
        + t**3 * np.array(p1)
    )
    pts[0], pts[-1] = p0, p1  # exactly the lanes' points, so the routing graph joins them
    return pts


def _stop_line(b: OsmBuilder, entry: LaneEnd) -> Any:
    return b.line([entry.left_xy, entry.right_xy], "stop_line")


def _sign_beside(b: OsmBuilder, entry: LaneEnd, subtype: str) -> Any:
    """A sign 1.5 m before the line and 1.5 m past the right curb, facing the approach."""
    h = entry.heading_rad
    x = entry.right_xy[0] - 1.5 * math.cos(h) + 1.5 * math.sin(h)
    y = entry.right_xy[1] - 1.5 * math.sin(h) - 1.5 * math.cos(h)
    return b.sign(x, y, h, subtype)


def _all_way_stop(b: OsmBuilder, junction: Junction, name: str, referenced: bool) -> None:
    """Every approach stops (de206 signs); the rule lists the approaches and their lines. Unless
    ``referenced``, no lanelet references the rule (maps drawn from the rule's side do that; a reader
    must still find the lines)."""
    with_lines = [ll2.LaneletWithStopLine(e.lanelet, _stop_line(b, e)) for e in junction.entries]
    signs = [_sign_beside(b, e, "de206") for e in junction.entries]
    rule = ll2.AllWayStop(b.new_id(), ll2.AttributeMap({"name": name}), with_lines, signs)
    if referenced:
        for entry in junction.entries:
            entry.lanelet.addRegulatoryElement(rule)
    b.map.add(rule)


def _signals(b: OsmBuilder, junction: Junction) -> None:
    """A ``traffic_light`` rule per approach, its head over the lane on the junction's far side."""
    for entry in junction.entries:
        h = entry.heading_rad
        cx = (entry.left_xy[0] + entry.right_xy[0]) / 2 + 2 * JUNCTION_HALF_M * math.cos(h)
        cy = (entry.left_xy[1] + entry.right_xy[1]) / 2 + 2 * JUNCTION_HALF_M * math.sin(h)
        head = b.traffic_light_head(cx, cy, HEAD_Z_M, h, HEAD_W_M, HEAD_H_M)
        rule = ll2.TrafficLight(
            b.new_id(), ll2.AttributeMap({"name": "Main St / East Ave"}), [head], _stop_line(b, entry)
        )
        entry.lanelet.addRegulatoryElement(rule)
        b.map.add(rule)


def _give_way(b: OsmBuilder, junction: Junction) -> None:
    """North Street's lanes yield to East Avenue's through traffic at one line across both lanes."""
    yielding = [k for k, e in enumerate(junction.entries) if e.heading_rad % (2 * math.pi) < 1e-6]
    lanes = [junction.entries[k] for k in yielding]
    left = max(lanes, key=lambda e: e.rank).left_xy
    right = min(lanes, key=lambda e: e.rank).right_xy
    line = b.line([left, right], "stop_line")
    yield_lls = [ll for (i, _), ll in sorted(junction.movements.items()) if i in yielding]
    priority = [ll for (i, _), ll in sorted(junction.movements.items()) if i not in yielding]
    yield_lls += [e.lanelet for e in lanes]
    _sign_beside(b, min(lanes, key=lambda e: e.rank), "de205")
    rule = ll2.RightOfWay(
        b.new_id(), ll2.AttributeMap({"name": "North St / East Ave"}), priority, yield_lls, line
    )
    for lanelet in priority + yield_lls:
        lanelet.addRegulatoryElement(rule)
    b.map.add(rule)


def _crosswalk(b: OsmBuilder, centre: tuple[float, float], road_heading_rad: float) -> None:
    """A zebra across a road whose axis passes ``centre`` along ``road_heading_rad``."""
    ux, uy = math.cos(road_heading_rad), math.sin(road_heading_rad)
    nx, ny = -uy, ux
    sides = []
    for d in (-CROSSWALK_W_M / 2, CROSSWALK_W_M / 2):
        x, y = centre[0] + d * ux, centre[1] + d * uy
        sides.append([(x - LW * nx, y - LW * ny), (x + LW * nx, y + LW * ny)])
    b.lanelet(
        b.line(sides[0], "line_thin", "dashed"),
        b.line(sides[1], "line_thin", "dashed"),
        10,
        subtype="crosswalk",
        **{"participant:pedestrian": "yes"},
    )
    b.sign(
        centre[0] - (CROSSWALK_W_M + 2) * ux - (LW + 1.5) * nx,
        centre[1] - (CROSSWALK_W_M + 2) * uy - (LW + 1.5) * ny,
        road_heading_rad,
        "de350",
    )


def _poles(b: OsmBuilder) -> None:
    """Light poles behind the outer curbs of the block's four streets."""
    edges = [((A[0], A[1] - LW - POLE_OFFSET_M), (B[0], B[1] - LW - POLE_OFFSET_M))]
    edges.append(((C[0], C[1] + LW + POLE_OFFSET_M), (D[0], D[1] + LW + POLE_OFFSET_M)))
    edges.append(((A[0] - LW - POLE_OFFSET_M, A[1]), (C[0] - LW - POLE_OFFSET_M, C[1])))
    edges.append(((B[0] + LW + POLE_OFFSET_M, B[1]), (D[0] + LW + POLE_OFFSET_M, D[1])))
    for p, q in edges:
        length = math.hypot(q[0] - p[0], q[1] - p[1])
        for k in range(1, int(length // POLE_SPACING_M) + 1):
            f = (k * POLE_SPACING_M - POLE_SPACING_M / 2) / length
            if f >= 1:
                break
            x, y = p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1])
            b.point(x, y, POLE_HEIGHT_M, type="pole", subtype="light_pole")


def write_town_map(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    projector = UtmProjector(Origin(ORIGIN_LAT_DEG, ORIGIN_LON_DEG))
    write(str(path), build_town_map(), projector)
    return path


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m lastmile.hdmap.town OUT.osm")
    print(write_town_map(Path(sys.argv[1])))
