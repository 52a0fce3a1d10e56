import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lastmile.core.errors import MessageError
from lastmile.core.geometry import (
    SE2,
    PreparedPolygon,
    convex_polygons_overlap,
    point_in_polygon,
    rectangle_corners_m,
)

finite = st.floats(-1e3, 1e3)
angle = st.floats(-math.pi, math.pi)


@given(finite, finite, angle, finite, finite, angle)
def test_compose_with_inverse_is_identity(x, y, yaw, x2, y2, yaw2):
    a, b = SE2(x, y, yaw), SE2(x2, y2, yaw2)
    back = a.compose(b).compose(b.inverse())
    assert back.x_m == pytest.approx(a.x_m, abs=1e-6)
    assert back.y_m == pytest.approx(a.y_m, abs=1e-6)
    assert math.cos(back.yaw_rad - a.yaw_rad) == pytest.approx(1.0, abs=1e-9)


def test_apply_points_agrees_with_apply():
    t = SE2(1.0, 2.0, 0.7)
    pts = np.array([[1.0, 0.0], [0.0, 3.0]])
    assert np.allclose(t.apply_points(pts), [t.apply(*p) for p in pts])


def test_nan_pose_is_rejected_with_what_was_expected():
    with pytest.raises(MessageError, match="expected finite"):
        SE2(float("nan"), 0.0, 0.0)


def test_separating_axis_overlap_and_separation():
    a = rectangle_corners_m(0.0, 0.0, 0.0, 4.0, 2.0)
    assert convex_polygons_overlap(a, rectangle_corners_m(3.0, 0.0, 0.5, 4.0, 2.0))
    assert not convex_polygons_overlap(a, rectangle_corners_m(0.0, 2.5, 0.0, 4.0, 2.0))


def test_rear_axle_box_spans_overhang_to_front():
    c = rectangle_corners_m(0.0, 0.0, 0.0, 4.6, 2.0, rear_overhang_m=0.85)
    assert c[:, 0].min() == pytest.approx(-0.85)
    assert c[:, 0].max() == pytest.approx(3.75)


def test_point_in_polygon_even_odd():
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    assert point_in_polygon(1.0, 1.0, square)
    assert not point_in_polygon(3.0, 1.0, square)


def _even_odd_vectorised(x_m, y_m, poly):
    # The textbook vectorised form, kept here as the reference the scalar loops must agree with.
    xi, yi = poly[:, 0], poly[:, 1]
    xj, yj = np.roll(xi, 1), np.roll(yi, 1)
    crosses = (yi > y_m) != (yj > y_m)
    x_cross = (xj[crosses] - xi[crosses]) * (y_m - yi[crosses]) / (yj[crosses] - yi[crosses]) + xi[crosses]
    return bool(np.count_nonzero(x_m < x_cross) % 2)


@given(
    st.lists(st.tuples(st.floats(-20, 20), st.floats(-20, 20)), min_size=3, max_size=12),
    st.lists(st.tuples(st.floats(-25, 25), st.floats(-25, 25)), min_size=1, max_size=20),
)
def test_prepared_polygon_and_point_in_polygon_agree_with_the_vectorised_rule(vertices, points):
    poly = np.array(vertices, dtype=float)
    prepared = PreparedPolygon(poly)
    for x, y in [*points, *vertices]:
        expected = _even_odd_vectorised(x, y, poly)
        assert point_in_polygon(x, y, poly) == expected
        assert prepared.contains(x, y) == expected


def test_prepared_polygon_rejects_a_degenerate_or_nan_polygon_naming_what_it_expected():
    with pytest.raises(MessageError, match="expected an"):
        PreparedPolygon(np.array([[0.0, 0.0], [1.0, 1.0]]))
    with pytest.raises(MessageError, match="finite"):
        PreparedPolygon(np.array([[0.0, 0.0], [1.0, float("nan")], [1.0, 0.0]]))
