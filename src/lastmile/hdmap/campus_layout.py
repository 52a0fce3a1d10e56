"""Where everything on the built-in campus sits: the ring road's shape and the features along it.

The ring road's centre line is a rounded rectangle run counter-clockwise; positions along it are
road ``s`` from (CORNER_R_M, 0) heading east. The shuttle drives the outer lane (right-hand traffic,
counter-clockwise), so its right curb is the ring's outside, where the bus bays are.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.geometry import FloatArray

ORIGIN_LAT_DEG, ORIGIN_LON_DEG = 43.4723, -80.5449  # a campus in Waterloo, Ontario
RING_W_M, RING_H_M, CORNER_R_M = 760.0, 280.0, 40.0
LANE_W_M = 3.5
BAY_DEPTH_M, BAY_TAPER_M, BAY_PLATFORM_M = 3.0, 10.0, 24.0
ROAD_LIMIT_KMH, TURN_LIMIT_KMH, BAY_LIMIT_KMH, SIDE_LIMIT_KMH = 25, 15, 10, 30
ARC_STEP_M = 1.5  # vertex spacing on curves: fine enough for 3-point curvature at 40 m radius
STRAIGHT_STEP_M = 10.0

# The all-way-stop T: the side road meets the bottom of the ring from the south at x = 380.
T_X_M, T_HALF_M, SIDE_STOP_Y_M, SIDE_END_Y_M = 380.0, 10.0, -10.0, -150.0
# The parking-lot entrance on the top of the ring at x = 150, and the lot north of it.
PARK_X_M, PARK_HALF_M, PARK_THROAT_Y_M, PARK_LOT_Y_M = 150.0, 8.0, 288.0, 310.0


@dataclass(frozen=True, slots=True)
class StopSpec:
    id: str
    name: str
    centre_s_m: float


@dataclass(frozen=True, slots=True)
class CrosswalkSpec:
    id: str
    centre_s_m: float
    width_m: float = 4.0


@dataclass(frozen=True, slots=True)
class BuildingSpec:
    name: str
    x0_m: float
    y0_m: float
    x1_m: float
    y1_m: float
    height_m: float


class RingRoad:
    """The ring's centre line as exact straights and arcs, so every offset curve is exact too."""

    def __init__(self) -> None:
        r, w, h = CORNER_R_M, RING_W_M, RING_H_M
        quarter = math.pi * r / 2.0
        # (length, kind, start xy, start heading); counter-clockwise from the bottom straight.
        self._pieces: list[tuple[float, str, tuple[float, float], float]] = []
        starts = [((r, 0.0), 0.0), ((w, r), math.pi / 2), ((w - r, h), math.pi), ((0.0, h - r), -math.pi / 2)]
        lengths = [w - 2 * r, h - 2 * r, w - 2 * r, h - 2 * r]
        for (xy, heading), length in zip(starts, lengths, strict=True):
            self._pieces.append((length, "line", xy, heading))
            end = (xy[0] + length * math.cos(heading), xy[1] + length * math.sin(heading))
            self._pieces.append((quarter, "arc", end, heading))
        self.length_m = sum(p[0] for p in self._pieces)

    def pose(self, s_m: float) -> tuple[float, float, float]:
        """(x, y, heading) of the centre line at road s (wrapped)."""
        s_m %= self.length_m
        for length, kind, (x0, y0), h0 in self._pieces:
            if s_m <= length + 1e-9:
                if kind == "line":
                    return x0 + s_m * math.cos(h0), y0 + s_m * math.sin(h0), h0
                a = s_m / CORNER_R_M  # left turn of radius R: centre to the left of the start
                cx, cy = x0 - CORNER_R_M * math.sin(h0), y0 + CORNER_R_M * math.cos(h0)
                h = h0 + a
                return cx + CORNER_R_M * math.sin(h), cy - CORNER_R_M * math.cos(h), h
            s_m -= length
        raise AssertionError("unreachable: s wrapped into [0, length)")

    def on_straight(self, s0_m: float, s1_m: float) -> bool:
        """[s0, s1] lies on one straight piece of the ring."""
        base = 0.0
        for length, kind, _, _ in self._pieces:
            if base - 1e-9 <= s0_m and s1_m <= base + length + 1e-9:
                return kind == "line"
            base += length
        return False

    def vertex_s(self, s0_m: float, s1_m: float) -> list[float]:
        """Sample positions in [s0, s1]: both ends, every piece boundary, arcs at ARC_STEP_M."""
        out = {s0_m, s1_m}
        base = 0.0
        for length, kind, _, _ in self._pieces:
            step = ARC_STEP_M if kind == "arc" else STRAIGHT_STEP_M
            n = max(1, math.ceil(length / step))
            for i in range(n + 1):
                s = base + length * i / n
                if s0_m < s < s1_m:
                    out.add(s)
            base += length
        return sorted(out)

    def curve(self, s0_m: float, s1_m: float, d_m: float | FloatArray) -> FloatArray:
        """(N, 2) points of the curve offset ``d`` (left positive; scalar or per-sample) over [s0, s1]."""
        ss = self.vertex_s(s0_m, s1_m)
        dd = np.broadcast_to(np.asarray(d_m, dtype=float), (len(ss),)) if np.ndim(d_m) == 0 else d_m
        pts = []
        for s, d in zip(ss, np.asarray(dd, dtype=float), strict=True):
            x, y, h = self.pose(s)
            pts.append((x - d * math.sin(h), y + d * math.cos(h)))
        return np.asarray(pts)

    def s_of_x_bottom(self, x_m: float) -> float:
        return x_m - CORNER_R_M

    def s_of_y_right(self, y_m: float) -> float:
        return (RING_W_M - 2 * CORNER_R_M) + math.pi * CORNER_R_M / 2 + (y_m - CORNER_R_M)

    def s_of_x_top(self, x_m: float) -> float:
        return (
            self.s_of_y_right(RING_H_M - CORNER_R_M)
            + math.pi * CORNER_R_M / 2
            + (RING_W_M - CORNER_R_M - x_m)
        )

    def s_of_y_left(self, y_m: float) -> float:
        return self.s_of_x_top(CORNER_R_M) + math.pi * CORNER_R_M / 2 + (RING_H_M - CORNER_R_M - y_m)


RING = RingRoad()

STOPS = (
    StopSpec("S1", "Engineering", RING.s_of_x_bottom(560.0)),
    StopSpec("S2", "Library", RING.s_of_y_right(200.0)),
    StopSpec("S3", "Student Centre", RING.s_of_x_top(520.0)),
    StopSpec("S4", "Residences", RING.s_of_y_left(100.0)),
)
CROSSWALKS = (
    CrosswalkSpec("C1", RING.s_of_x_bottom(170.0)),
    CrosswalkSpec("C2", RING.s_of_y_right(140.0)),
    CrosswalkSpec("C3", RING.s_of_x_top(300.0)),
)
# The signalised crossing: crosswalk C2 gets a pedestrian signal (a "pelican" crossing). Each direction has
# a stop line SIGNAL_STOP_GAP_M before the crossing and two three-bulb heads just past it: one over the
# lane (bottom SIGNAL_OVERHEAD_Z_M) and one on a kerb pole (bottom SIGNAL_POLE_Z_M).
SIGNAL_CROSSWALK = "C2"
SIGNAL_STOP_GAP_M, SIGNAL_HEAD_PAST_M = 3.0, 2.0
SIGNAL_OVERHEAD_Z_M, SIGNAL_POLE_Z_M, SIGNAL_POLE_D_M = 5.0, 2.6, 1.2
SIGNAL_HEAD_W_M, SIGNAL_HEAD_H_M = 0.35, 1.0
_SIGNAL_CW = next(c for c in CROSSWALKS if c.id == SIGNAL_CROSSWALK)
# Ring s of the shuttle's (ccw, outer lane) stop line and of the oncoming (cw, inner lane) one.
SIGNAL_CCW_STOP_S_M = _SIGNAL_CW.centre_s_m - _SIGNAL_CW.width_m / 2 - SIGNAL_STOP_GAP_M
SIGNAL_CW_STOP_S_M = _SIGNAL_CW.centre_s_m + _SIGNAL_CW.width_m / 2 + SIGNAL_STOP_GAP_M
T_S0_M, T_S1_M = RING.s_of_x_bottom(T_X_M - T_HALF_M), RING.s_of_x_bottom(T_X_M + T_HALF_M)
PARK_S0_M, PARK_S1_M = RING.s_of_x_top(PARK_X_M + PARK_HALF_M), RING.s_of_x_top(PARK_X_M - PARK_HALF_M)
BUILDINGS = (
    BuildingSpec("Engineering 5", 500.0, -70.0, 620.0, -22.0, 18.0),
    BuildingSpec("Physics", 80.0, -60.0, 170.0, -25.0, 14.0),
    BuildingSpec("Gym", 640.0, -65.0, 720.0, -25.0, 10.0),
    BuildingSpec("Library", 785.0, 120.0, 830.0, 250.0, 22.0),
    BuildingSpec("Student Centre", 470.0, 300.0, 590.0, 345.0, 12.0),
    BuildingSpec("Arts", 240.0, 300.0, 330.0, 340.0, 16.0),
    BuildingSpec("Residence A", -70.0, 60.0, -25.0, 150.0, 20.0),
    BuildingSpec("Residence B", -70.0, 170.0, -25.0, 240.0, 20.0),
    BuildingSpec("Mathematics", 90.0, 40.0, 230.0, 95.0, 16.0),
    BuildingSpec("Chemistry", 440.0, 170.0, 600.0, 235.0, 15.0),
    BuildingSpec("Dining Hall", 620.0, 50.0, 700.0, 110.0, 8.0),
)
LIGHT_POLE_SPACING_M, LIGHT_POLE_D_M, LIGHT_POLE_HEIGHT_M = 40.0, -9.0, 8.0


def bay_depth_m(u_m: float) -> float:
    """Bay depth ``u`` metres into the bay: cosine tapers in and out around the full-depth platform."""
    total = 2 * BAY_TAPER_M + BAY_PLATFORM_M
    edge = min(u_m, total - u_m)
    if edge >= BAY_TAPER_M:
        return BAY_DEPTH_M
    return BAY_DEPTH_M * 0.5 * (1.0 - math.cos(math.pi * max(edge, 0.0) / BAY_TAPER_M))


def arc(cx: float, cy: float, r_m: float, a0_rad: float, a1_rad: float) -> FloatArray:
    """(N, 2) points on a circle from angle a0 to a1 (either direction), about ARC_STEP_M apart."""
    n = max(2, math.ceil(abs(a1_rad - a0_rad) * r_m / ARC_STEP_M) + 1)
    a = np.linspace(a0_rad, a1_rad, n)
    return np.c_[cx + r_m * np.cos(a), cy + r_m * np.sin(a)]


def segment(p0: tuple[float, float], p1: tuple[float, float], step_m: float = STRAIGHT_STEP_M) -> FloatArray:
    n = max(2, math.ceil(math.dist(p0, p1) / step_m) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - t) * np.asarray(p0) + t * np.asarray(p1)


def passing_allowed(s0_m: float, s1_m: float) -> bool:
    """The ring's centre line between road s0 and s1 is broken (a driver may cross it to pass an
    obstruction): on a straight, with no crosswalk, signal stop line or junction mouth on the stretch.
    Road markings keep such places (and the corners, where the view ahead is short) solid."""
    if not RING.on_straight(s0_m, s1_m):
        return False
    features = [c.centre_s_m for c in CROSSWALKS] + [SIGNAL_CCW_STOP_S_M, SIGNAL_CW_STOP_S_M]
    mouths = [(T_S0_M, T_S1_M), (PARK_S0_M, PARK_S1_M)]
    if any(s0_m <= f <= s1_m for f in features):
        return False
    return not any(a < s1_m and s0_m < b for a, b in mouths)
