"""The rest offset beside a curb: the straight body keeps the gap along a curb that curves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.geometry import rectangle_corners_m
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.curb_fit import body_side_clearance_m, spot_offset_m

GEOMETRY = VehicleGeometry()
GAP_M = 0.2


def _arc(radius_m: float, left: bool) -> Polyline:
    """A 60 m route: 20 m straight, then an arc of ``radius_m`` turning left (or right)."""
    straight = np.c_[np.arange(0.0, 20.0, 0.5), np.zeros(40)]
    phi = np.arange(0.0, 40.0 / radius_m, 0.5 / radius_m)
    sign = 1.0 if left else -1.0
    arc = np.c_[20.0 + radius_m * np.sin(phi), sign * radius_m * (1.0 - np.cos(phi))]
    return Polyline(np.vstack([straight, arc]))


def _worst_corner_gap_m(route: Polyline, rear_s_m: float, d_m: float, curb_d_m: float) -> float:
    """The right corners' gap to the curb line for the body headed along the route at its rear axle."""
    x, y, h = route.point_at(rear_s_m)
    rx, ry = x - d_m * math.sin(h), y + d_m * math.cos(h)
    corners = rectangle_corners_m(rx, ry, h, GEOMETRY.length_m, GEOMETRY.width_m, GEOMETRY.rear_overhang_m)
    gaps = [route.project(float(cx), float(cy), hint_s_m=rear_s_m).d_m - curb_d_m for cx, cy in corners[2:]]
    return min(gaps)


def test_straight_curb_keeps_the_plain_offset_exactly() -> None:
    route = Polyline(np.c_[np.arange(0.0, 60.0, 1.0), np.zeros(60)])
    curb = -1.8
    assert spot_offset_m(route, 20.0, curb, GAP_M, GEOMETRY) == curb + GAP_M + GEOMETRY.width_m / 2.0
    assert body_side_clearance_m(route, 20.0, -0.6, curb, GEOMETRY) == pytest.approx(GAP_M)


@pytest.mark.parametrize("left", [True, False])
def test_curved_curb_keeps_the_gap_along_the_whole_body(left: bool) -> None:
    """Outside of a bend (left turn, curb right): the plain offset puts the front corner over the
    curb line. Inside (right turn): the body's middle bulges towards it. The fitted offset keeps the
    gap at both headings the body may rest at, and moves away from the curb only as far as needed."""
    route, curb, rear_s = _arc(12.0, left), -1.8, 22.0
    plain = curb + GAP_M + GEOMETRY.width_m / 2.0
    assert body_side_clearance_m(route, rear_s, plain, curb, GEOMETRY) < GAP_M - 0.05
    d = spot_offset_m(route, rear_s, curb, GAP_M, GEOMETRY)
    assert d > plain
    assert body_side_clearance_m(route, rear_s, d, curb, GEOMETRY) == pytest.approx(GAP_M, abs=0.01)
    assert _worst_corner_gap_m(route, rear_s, d, curb) >= GAP_M - 0.01
    if left:  # the case that left the road on the Lanelet2 example map: the front corner swings out
        assert _worst_corner_gap_m(route, rear_s, plain, curb) < 0.0


def test_the_door_gap_is_the_target_on_a_straight_kerb_and_grows_with_the_bend() -> None:
    """The door (the middle of the body's side) of a body kept ``GAP_M`` off the kerb: exactly the
    target beside a straight kerb; beside a kerb on the outside of a bend, the body's corners are its
    nearest points and the door is farther by about the sagitta b^2 / 2R of half the body (b = 2.3 m),
    more when the body rests at the rear axle's heading; the tighter the bend, the farther."""
    from lastmile.hdmap.curb_fit import rest_door_gap_m

    straight = Polyline(np.c_[np.arange(0.0, 60.0, 1.0), np.zeros(60)])
    assert rest_door_gap_m(straight, 30.0, -1.8, GAP_M, GEOMETRY) == pytest.approx(GAP_M, abs=1e-9)
    b = GEOMETRY.length_m / 2.0
    gaps = []
    for radius in (60.0, 12.0, 6.0):
        route = _arc(radius, left=True)
        door = rest_door_gap_m(route, 20.0 + 15.0, -1.8, GAP_M, GEOMETRY)  # well into the arc
        assert door >= GAP_M + b**2 / (2.0 * (radius + 1.8)) - 0.02
        gaps.append(door)
    assert gaps[0] < gaps[1] < gaps[2] and gaps[2] > 0.5  # a 6 m bend: no kerbside stop there
