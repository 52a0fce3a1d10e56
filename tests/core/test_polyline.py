import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lastmile.core.errors import MessageError
from lastmile.core.polyline import Polyline

SQUARE = Polyline(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]), closed=True)


def test_arc_length_of_a_closed_square_is_its_perimeter():
    assert SQUARE.length_m == pytest.approx(40.0)


def test_point_at_wraps_on_a_loop():
    assert SQUARE.point_at(45.0)[:2] == pytest.approx((5.0, 0.0))


@given(st.floats(0.0, 39.9), st.floats(-2.0, 2.0))
def test_projection_recovers_frenet_coordinates_on_straight_sides(s_m, d_m):
    # Stay away from corners, where the nearest point is the corner itself.
    side_s = s_m % 10.0
    if side_s < 2.5 or side_s > 7.5:
        return
    x, y, heading = SQUARE.point_at(s_m)
    px, py = x - d_m * math.sin(heading), y + d_m * math.cos(heading)
    f = SQUARE.project(px, py, hint_s_m=s_m + 1.0)
    assert f.s_m == pytest.approx(s_m, abs=1e-6)
    assert f.d_m == pytest.approx(d_m, abs=1e-6)


def test_hinted_projection_matches_global_projection():
    rng = np.random.default_rng(0)
    for _ in range(50):
        x, y = rng.uniform(-3, 13, size=2)
        glob = SQUARE.project(float(x), float(y))
        local = SQUARE.project(float(x), float(y), hint_s_m=glob.s_m + 2.0)
        assert local.d_m == pytest.approx(glob.d_m, abs=1e-9)


def test_open_line_projection_extends_beyond_its_ends():
    line = Polyline(np.array([[0.0, 0.0], [10.0, 0.0]]))
    assert line.project(-3.0, 1.0).s_m == pytest.approx(-3.0)
    assert line.project(12.0, -1.0).d_m == pytest.approx(-1.0)


def test_offset_keeps_distance_on_a_straight_line():
    line = Polyline(np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]]))
    assert np.allclose(line.offset(-1.5).xy_m[:, 1], -1.5)


def test_curvature_of_a_circle_is_one_over_radius_left_positive():
    theta = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    circle = Polyline(40.0 * np.c_[np.cos(theta), np.sin(theta)], closed=True)
    assert circle.curvature_at(30.0) == pytest.approx(1 / 40.0, rel=0.02)


@pytest.mark.parametrize("bad", [np.zeros((1, 2)), np.zeros((3, 3)), np.array([[0.0, 0.0], [np.nan, 1.0]])])
def test_malformed_vertices_raise_a_message_error(bad):
    with pytest.raises(MessageError, match="expected"):
        Polyline(bad)


@given(
    st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=30, max_size=80, unique=True),
    st.booleans(),
    st.floats(-60, 60),
    st.floats(-60, 60),
)
def test_vectorised_projection_is_bit_identical_to_the_scalar_loop(vertices, closed, x_m, y_m):
    try:
        line = Polyline(np.array(vertices, dtype=float), closed=closed)
    except MessageError:
        return  # degenerate (collapsed) vertex sets are rejected, which another test covers
    n = len(line.s_m) - 1
    if n <= 24:
        return
    vectorised = line._project_range(x_m, y_m, range(n))  # a long range takes the NumPy path
    scalar = line._project_range(x_m, y_m, list(range(n)))  # a list always takes the loop
    assert (vectorised.s_m, vectorised.d_m, vectorised.segment) == (scalar.s_m, scalar.d_m, scalar.segment)


def test_ds_is_the_shorter_way_round_on_a_loop_and_the_difference_on_an_open_line():
    assert SQUARE.closed and SQUARE.length_m == pytest.approx(40.0)
    assert SQUARE.ds_m(38.0, 2.0) == pytest.approx(4.0)  # across the start, ahead
    assert SQUARE.ds_m(2.0, 38.0) == pytest.approx(-4.0)  # across the start, behind
    assert SQUARE.ds_m(5.0, 15.0) == pytest.approx(10.0)
    assert SQUARE.ds_m(0.0, 20.0) == pytest.approx(-20.0)  # half a lap: [-L/2, L/2)
    line = Polyline(np.array([[0.0, 0.0], [40.0, 0.0]]))
    assert line.ds_m(38.0, 2.0) == pytest.approx(-36.0)
