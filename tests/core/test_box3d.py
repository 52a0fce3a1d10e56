"""3D box overlap: exact on hand cases, symmetric, bounded, robust to identical and degenerate boxes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.box3d import (
    bev_intersection_pairs,
    boxes_from_kitti_camera,
    check_boxes,
    iou3d_matrix,
    iou3d_pairs,
    kitti_camera_from_boxes,
)
from lastmile.core.errors import MessageError


def _box(x=0.0, y=0.0, z=0.0, length=4.0, width=2.0, height=1.5, yaw=0.0) -> np.ndarray:
    return np.array([[x, y, z, length, width, height, yaw]])


def test_identical_boxes_have_iou_one_at_any_heading() -> None:
    for yaw in (0.0, 0.3, np.pi / 2, -2.0, np.pi):
        b = _box(yaw=yaw)
        assert iou3d_pairs(b, b)[0] == pytest.approx(1.0, abs=1e-9)


def test_box_turned_half_a_turn_is_the_same_box() -> None:
    assert iou3d_pairs(_box(yaw=0.4), _box(yaw=0.4 + np.pi))[0] == pytest.approx(1.0, abs=1e-9)


def test_quarter_turn_of_a_4x2_box_overlaps_one_third() -> None:
    # 2 x 2 common square over 8 + 8 - 4 square metres.
    assert iou3d_pairs(_box(), _box(yaw=np.pi / 2))[0] == pytest.approx(1.0 / 3.0, abs=1e-9)


def test_half_shifted_box_and_height_overlap_multiply() -> None:
    # Shifted by half its length: BEV IoU 4 / 12; then by half its height as well: 2 / 14.
    assert iou3d_pairs(_box(), _box(x=2.0))[0] == pytest.approx(4.0 / 12.0)
    assert iou3d_pairs(_box(), _box(x=2.0, z=0.75))[0] == pytest.approx(2.0 / 14.0)


def test_disjoint_touching_and_zero_volume_boxes_give_zero_not_nan() -> None:
    assert iou3d_pairs(_box(), _box(x=10.0))[0] == 0.0
    assert iou3d_pairs(_box(), _box(x=4.0))[0] == pytest.approx(0.0, abs=1e-9)
    flat = _box(length=0.0, width=0.0, height=0.0)
    assert iou3d_pairs(flat, flat)[0] == 0.0


def test_matrix_matches_pairs_and_skips_far_pairs() -> None:
    a = np.vstack([_box(), _box(x=1.0, yaw=0.2), _box(x=50.0)])
    b = np.vstack([_box(x=0.5), _box(y=30.0)])
    m = iou3d_matrix(a, b)
    assert m.shape == (3, 2)
    for i in range(3):
        for j in range(2):
            assert m[i, j] == pytest.approx(iou3d_pairs(a[i : i + 1], b[j : j + 1])[0])
    assert iou3d_matrix(a[:0], b).shape == (0, 2)


def test_kitti_camera_conversion_round_trips_and_faces_forward() -> None:
    cam = np.array([[1.5, 1.6, 3.9, 2.0, 1.7, 20.0, -np.pi / 2]])
    up = boxes_from_kitti_camera(cam)
    assert up[0, 0] == pytest.approx(20.0) and up[0, 1] == pytest.approx(-2.0)
    assert up[0, 2] == pytest.approx(-1.7 + 0.75) and up[0, 6] == pytest.approx(0.0)
    assert np.allclose(kitti_camera_from_boxes(up), cam)


def test_check_boxes_refuses_bad_shapes_and_negative_extents() -> None:
    with pytest.raises(MessageError, match=r"shape \(N, 7\)"):
        check_boxes(np.zeros((2, 6)), "boxes")
    with pytest.raises(MessageError, match="non-negative"):
        check_boxes(_box(length=-1.0), "boxes")


_coord = st.floats(-3.0, 3.0)
_ext = st.floats(0.3, 5.0)
_ang = st.floats(-4.0, 4.0)


@settings(max_examples=60, deadline=None)
@given(_coord, _coord, _ext, _ext, _ang, _coord, _coord, _ext, _ext, _ang)
def test_bev_intersection_is_symmetric_bounded_and_matches_sampling(
    x1, y1, l1, w1, a1, x2, y2, l2, w2, a2
) -> None:
    a = _box(x=x1, y=y1, length=l1, width=w1, yaw=a1)
    b = _box(x=x2, y=y2, length=l2, width=w2, yaw=a2)
    ab = bev_intersection_pairs(a, b)[0]
    assert ab == pytest.approx(bev_intersection_pairs(b, a)[0], abs=1e-9)
    assert -1e-9 <= ab <= min(l1 * w1, l2 * w2) + 1e-9
    # Grid sampling of the smaller box: the fraction of its points inside the other box.
    small, other = (a, b) if l1 * w1 <= l2 * w2 else (b, a)
    u = (np.arange(60) + 0.5) / 60 - 0.5
    gx, gy = np.meshgrid(u * small[0, 3], u * small[0, 4])
    c, s = np.cos(small[0, 6]), np.sin(small[0, 6])
    px = small[0, 0] + c * gx - s * gy - other[0, 0]
    py = small[0, 1] + s * gx + c * gy - other[0, 1]
    co, so = np.cos(other[0, 6]), np.sin(other[0, 6])
    lx, ly = co * px + so * py, -so * px + co * py
    inside = (np.abs(lx) <= other[0, 3] / 2) & (np.abs(ly) <= other[0, 4] / 2)
    sampled = inside.mean() * small[0, 3] * small[0, 4]
    assert ab == pytest.approx(sampled, abs=0.05 * small[0, 3] * small[0, 4] + 1e-6)


def test_nested_box_overlap_is_the_small_box() -> None:
    big, small = _box(length=6.0, width=4.0, yaw=0.3), _box(x=0.5, length=1.0, width=0.5, yaw=1.1)
    assert bev_intersection_pairs(big, small)[0] == pytest.approx(0.5)
    assert bev_intersection_pairs(small, big)[0] == pytest.approx(0.5)
