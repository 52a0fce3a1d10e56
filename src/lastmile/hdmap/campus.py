"""Generates the built-in campus map as a real Lanelet2 OSM file (``python -m lastmile.hdmap.campus``).

A 2 km ring road, one lane each way; four bus stops with pull-in bays at the outer curb; an all-way-stop
T intersection with a side road; three crosswalks; a parking-lot entrance; curbs; light poles, building
facades and traffic signs as landmarks. Lanelets that follow each other share their end points, and
side-by-side lanelets share their boundary line string, so Lanelet2's routing graph sees what a
surveyor's map would give it. ``campus.osm`` beside this file is its output; a test keeps them equal.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import lanelet2.core as ll2
from lanelet2.io import Origin, write
from lanelet2.projection import UtmProjector

from lastmile.hdmap import campus_layout as lay
from lastmile.hdmap.campus_layout import RING, arc, segment
from lastmile.hdmap.osm_builder import OsmBuilder

CAMPUS_OSM = Path(__file__).with_name("data") / "campus.osm"
LW = lay.LANE_W_M


def build_campus_map() -> Any:
    """The campus as a ``lanelet2.core.LaneletMap`` in local metres (x east, y north)."""
    b = OsmBuilder()
    ring_out, ring_in = _ring(b)
    _intersection(b, ring_out, ring_in)
    _parking(b)
    _signal(b, ring_out, ring_in)
    for cw in lay.CROSSWALKS:
        _crosswalk(b, cw)
    for spec in lay.BUILDINGS:
        corners = [
            (spec.x0_m, spec.y0_m),
            (spec.x1_m, spec.y0_m),
            (spec.x1_m, spec.y1_m),
            (spec.x0_m, spec.y1_m),
        ]
        b.area(corners, "building", "wall", name=spec.name, height=f"{spec.height_m:g}")
    _light_poles(b)
    return b.map


def _cuts() -> list[float]:
    cuts = {0.0, lay.T_S0_M, lay.T_S1_M, lay.PARK_S0_M, lay.PARK_S1_M}
    cuts |= {lay.SIGNAL_CCW_STOP_S_M, lay.SIGNAL_CW_STOP_S_M}  # stop lines sit at lanelet ends
    half = lay.BAY_TAPER_M + lay.BAY_PLATFORM_M / 2
    for stop in lay.STOPS:
        cuts |= {stop.centre_s_m - half, stop.centre_s_m + half}
    # Corners get their own lanelets so no lanelet is much longer than a block.
    cuts |= {RING.s_of_y_right(lay.CORNER_R_M), RING.s_of_x_top(lay.RING_W_M - lay.CORNER_R_M)}
    cuts |= {
        RING.s_of_y_left(lay.RING_H_M - lay.CORNER_R_M),
        RING.s_of_x_bottom(lay.RING_W_M - lay.CORNER_R_M),
    }
    return sorted(cuts)


def _ring(b: OsmBuilder) -> tuple[dict[float, Any], dict[float, Any]]:
    """Ring lanelets; returns the outer-lane (shuttle) and inner-lane lanelets keyed by segment start s."""
    cuts = _cuts()
    stops = {round(s.centre_s_m - lay.BAY_TAPER_M - lay.BAY_PLATFORM_M / 2, 6): s for s in lay.STOPS}
    outer: dict[float, Any] = {}
    inner: dict[float, Any] = {}
    for s0, s1 in zip(cuts, [*cuts[1:], RING.length_m], strict=True):
        stop = stops.get(round(s0, 6))
        opening = s0 in (lay.T_S0_M, lay.PARK_S0_M)
        edge_type, edge_sub = ("virtual", "") if opening else ("curbstone", "high")
        if stop is not None:
            edge_type, edge_sub = "line_thin", "dashed"  # the lane's edge is the bay's painted line
        marking = "dashed" if lay.passing_allowed(s0, s1) else "solid"
        divider = b.line(RING.curve(s0, s1, 0.0), "line_thin", marking)
        edge = b.line(RING.curve(s0, s1, -LW), edge_type, edge_sub)
        far = b.line(RING.curve(s0, s1, LW), "curbstone", "high")
        extra = {"turn_direction": "straight"} if opening else {}
        outer[s0] = b.lanelet(divider, edge, lay.ROAD_LIMIT_KMH, **extra)
        inner[s0] = b.lanelet(divider.invert(), far.invert(), lay.ROAD_LIMIT_KMH, **extra)
        if stop is not None:
            _bay(b, stop, s0, s1, edge)
    return outer, inner


def _bay(b: OsmBuilder, stop: lay.StopSpec, s0: float, s1: float, lane_edge: Any) -> None:
    n = round(s1 - s0) + 1  # a vertex a metre: the tapers are curves
    ss = [s0 + (s1 - s0) * i / (n - 1) for i in range(n)]
    pts = []
    for s in ss:
        x, y, h = RING.pose(s)
        d = -LW - lay.bay_depth_m(s - s0)
        pts.append((x - d * math.sin(h), y + d * math.cos(h)))
    curb = b.line(pts, "curbstone", "high")
    b.lanelet(lane_edge, curb, lay.BAY_LIMIT_KMH, **{"lastmile:bus_stop": stop.id, "name": stop.name})
    x, y, h = RING.pose(stop.centre_s_m)
    d = -LW - lay.BAY_DEPTH_M - 1.5
    b.sign(x - d * math.sin(h), y + d * math.cos(h), h, "de224")


def _intersection(b: OsmBuilder, ring_out: dict[float, Any], ring_in: dict[float, Any]) -> None:
    """The all-way-stop T: side road from the south; every approach has a stop line and a stop sign."""
    xt, x0, x1 = lay.T_X_M, lay.T_X_M - lay.T_HALF_M, lay.T_X_M + lay.T_HALF_M
    ys, ye = lay.SIDE_STOP_Y_M, lay.SIDE_END_Y_M
    div = b.line(segment((xt, ye), (xt, ys)), "line_thin", "solid")
    east = b.line(segment((xt + LW, ye), (xt + LW, ys)), "curbstone", "high")
    west = b.line(segment((xt - LW, ys), (xt - LW, ye)), "curbstone", "high")
    north = b.lanelet(div, east, lay.SIDE_LIMIT_KMH)
    b.lanelet(div.invert(), west, lay.SIDE_LIMIT_KMH)
    half_pi = math.pi / 2
    turns = [  # (left bound, right bound, direction): radii so every end meets its lane's bounds
        (arc(x1, ys, 10.0, math.pi, half_pi), arc(x1, ys, 6.5, math.pi, half_pi), "right"),  # N -> E
        (arc(x0, ys, 10.0, 0.0, half_pi), arc(x0, ys, 13.5, 0.0, half_pi), "left"),  # N -> W
        (arc(x0, ys, 10.0, half_pi, 0.0), arc(x0, ys, 6.5, half_pi, 0.0), "right"),  # E-bound -> S
        (arc(x1, ys, 10.0, half_pi, math.pi), arc(x1, ys, 13.5, half_pi, math.pi), "left"),  # W-bound -> S
    ]
    for left, right, direction in turns:
        right_type = ("curbstone", "high") if direction == "right" else ("virtual", "")
        b.lanelet(
            b.line(left, "virtual"), b.line(right, *right_type), lay.TURN_LIMIT_KMH, turn_direction=direction
        )
    cuts = _cuts()
    eb_entry = ring_out[cuts[cuts.index(lay.T_S0_M) - 1]]
    wb_entry = ring_in[lay.T_S1_M]
    lines = [
        (eb_entry, ((x0, 0.0), (x0, -LW)), (x0 - 1.5, -LW - 1.5, 0.0)),
        (wb_entry, ((x1, 0.0), (x1, LW)), (x1 + 1.5, LW + 1.5, math.pi)),
        (north, ((xt, ys), (xt + LW, ys)), (xt + LW + 1.5, ys - 1.5, half_pi)),
    ]
    with_lines, signs = [], []
    for lanelet, line_xy, (sx, sy, heading) in lines:
        stop_line = b.line(line_xy, "stop_line")
        with_lines.append(ll2.LaneletWithStopLine(lanelet, stop_line))
        signs.append(b.sign(sx, sy, heading, "de206"))
    rule = ll2.AllWayStop(
        b.new_id(), ll2.AttributeMap({"name": "Ring Road / South Access"}), with_lines, signs
    )
    for lanelet, _, _ in lines:
        lanelet.addRegulatoryElement(rule)
    b.map.add(rule)


def _signal(b: OsmBuilder, ring_out: dict[float, Any], ring_in: dict[float, Any]) -> None:
    """The signalised crossing at C2: a Lanelet2 ``traffic_light`` rule per direction.

    Each rule refers to its two heads (``traffic_light`` line strings drawn across the bottom of the
    housing, ``height`` the housing's height) and its stop line; each head's bulbs are a ``light_bulbs``
    line string (Autoware's convention: points tagged ``color``, the head's id in ``traffic_light_id``).
    """
    cuts = _cuts()
    directions = [  # (entry lanelet, stop-line s, head s, lane side: -1 outer (right of ring), +1 inner)
        (ring_out[cuts[cuts.index(lay.SIGNAL_CCW_STOP_S_M) - 1]], lay.SIGNAL_CCW_STOP_S_M, -1.0),
        (ring_in[lay.SIGNAL_CW_STOP_S_M], lay.SIGNAL_CW_STOP_S_M, 1.0),
    ]
    cw = next(c for c in lay.CROSSWALKS if c.id == lay.SIGNAL_CROSSWALK)
    for lanelet, stop_s, side in directions:
        # Traffic in this lane drives along +s (outer) or -s (inner); heads stand past the crossing.
        sign_s = 1.0 if side < 0 else -1.0
        x, y, h = RING.pose(stop_s)
        nx, ny = -math.sin(h), math.cos(h)  # left normal of the ring
        stop_line = b.line([(x, y), (x + side * LW * nx, y + side * LW * ny)], "stop_line")
        head_s = cw.centre_s_m + sign_s * (cw.width_m / 2 + lay.SIGNAL_HEAD_PAST_M)
        hx, hy, hh = RING.pose(head_s)
        hnx, hny = -math.sin(hh), math.cos(hh)
        heading = hh if side < 0 else hh + math.pi  # the controlled traffic's heading
        heads: list[Any] = []
        for d, z in (
            (side * LW / 2, lay.SIGNAL_OVERHEAD_Z_M),
            (side * (LW + lay.SIGNAL_POLE_D_M), lay.SIGNAL_POLE_Z_M),
        ):
            cx, cy = hx + d * hnx, hy + d * hny
            head = b.traffic_light_head(cx, cy, z, heading, lay.SIGNAL_HEAD_W_M, lay.SIGNAL_HEAD_H_M)
            heads.append(head)
        rule = ll2.TrafficLight(
            b.new_id(), ll2.AttributeMap({"name": f"{cw.id} pedestrian signal"}), heads, stop_line
        )
        lanelet.addRegulatoryElement(rule)
        b.map.add(rule)


def _parking(b: OsmBuilder) -> None:
    """Entrance and exit of the north parking lot, right turns off and onto the ring's outer lane."""
    xp, throat, lot = lay.PARK_X_M, lay.PARK_THROAT_Y_M, lay.PARK_LOT_Y_M
    xin, xout = xp + lay.PARK_HALF_M, xp - lay.PARK_HALF_M
    b.lanelet(
        b.line(arc(xin, throat, 8.0, -math.pi / 2, -math.pi), "virtual"),
        b.line(arc(xin, throat, 4.5, -math.pi / 2, -math.pi), "curbstone", "high"),
        lay.BAY_LIMIT_KMH,
        turn_direction="right",
    )
    b.lanelet(
        b.line(arc(xout, throat, 8.0, 0.0, -math.pi / 2), "virtual"),
        b.line(arc(xout, throat, 4.5, 0.0, -math.pi / 2), "curbstone", "high"),
        lay.BAY_LIMIT_KMH,
        turn_direction="right",
    )
    div = b.line([(xp, throat), (xp, lot)], "line_thin", "solid")
    b.lanelet(div, b.line([(xp + LW, throat), (xp + LW, lot)], "curbstone", "high"), lay.BAY_LIMIT_KMH)
    b.lanelet(
        div.invert(), b.line([(xp - LW, lot), (xp - LW, throat)], "curbstone", "high"), lay.BAY_LIMIT_KMH
    )
    corners = [(xp - 40.0, lot), (xp + 40.0, lot), (xp + 40.0, lot + 40.0), (xp - 40.0, lot + 40.0)]
    b.area(corners, "parking", "curbstone", name="Lot N")


def _crosswalk(b: OsmBuilder, spec: lay.CrosswalkSpec) -> None:
    """A zebra crossing across the whole road, walked from the outside in (and back: one_way=no)."""
    sides = []
    for s in (spec.centre_s_m - spec.width_m / 2, spec.centre_s_m + spec.width_m / 2):
        x, y, h = RING.pose(s)
        nx, ny = -math.sin(h), math.cos(h)
        sides.append([(x - LW * nx, y - LW * ny), (x + LW * nx, y + LW * ny)])
    b.lanelet(
        b.line(sides[0], "line_thin", "dashed"),
        b.line(sides[1], "line_thin", "dashed"),
        lay.BAY_LIMIT_KMH,
        subtype="crosswalk",
        **{"name": spec.id, "participant:pedestrian": "yes"},
    )
    x, y, h = RING.pose(spec.centre_s_m - spec.width_m)
    d = -LW - 1.5
    b.sign(x - d * math.sin(h), y + d * math.cos(h), h, "de350")


def _light_poles(b: OsmBuilder) -> None:
    openings = [(lay.T_S0_M - 6.0, lay.T_S1_M + 6.0), (lay.PARK_S0_M - 6.0, lay.PARK_S1_M + 6.0)]
    n = int(RING.length_m // lay.LIGHT_POLE_SPACING_M)
    for i in range(n):
        s = (i + 0.5) * lay.LIGHT_POLE_SPACING_M
        if any(a <= s <= c for a, c in openings):
            continue
        x, y, h = RING.pose(s)
        d = lay.LIGHT_POLE_D_M
        b.point(
            x - d * math.sin(h),
            y + d * math.cos(h),
            lay.LIGHT_POLE_HEIGHT_M,
            type="pole",
            subtype="light_pole",
        )


def write_campus_map(path: Path = CAMPUS_OSM) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    projector = UtmProjector(Origin(lay.ORIGIN_LAT_DEG, lay.ORIGIN_LON_DEG))
    write(str(path), build_campus_map(), projector)
    return path


if __name__ == "__main__":
    print(write_campus_map(Path(sys.argv[1]) if len(sys.argv) > 1 else CAMPUS_OSM))
