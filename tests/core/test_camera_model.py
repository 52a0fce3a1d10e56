"""The one pinhole camera model: mounting -> camera_from_base, optical centre, the two projections."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError

REAR = PinholeCamera.from_fov("rear", 2048, 1536, 70.0, -0.8, 0.1, 2.2, yaw_rad=math.pi, pitch_rad=0.1)


def test_the_optical_centre_maps_to_the_camera_origin_and_the_axis_to_the_principal_point() -> None:
    assert REAR.centre_base_m == (-0.8, 0.1, 2.2)
    assert np.allclose(REAR.to_camera([[-0.8, 0.1, 2.2]]), 0.0, atol=1e-12)
    # 10 m along the rear camera's axis: behind the shuttle, 0.1 rad down.
    ahead = [-0.8 - 10.0 * math.cos(0.1), 0.1, 2.2 - 10.0 * math.sin(0.1)]
    assert np.allclose(REAR.to_camera([ahead]), [[0.0, 0.0, 10.0]], atol=1e-9)
    assert np.allclose(REAR.pixels_from_camera(REAR.to_camera([ahead])), [[1024.0, 768.0]])


def test_the_centre_is_derived_from_the_transform_when_not_given() -> None:
    bare = PinholeCamera(
        camera_id="c", fx_px=REAR.fx_px, fy_px=REAR.fy_px, cx_px=REAR.cx_px, cy_px=REAR.cy_px,
        width_px=REAR.width_px, height_px=REAR.height_px, camera_from_base=REAR.camera_from_base,
    )  # fmt: skip
    assert np.allclose(bare.centre_base_m, REAR.centre_base_m, atol=1e-12)
    assert (bare.x_m, bare.y_m, bare.z_m) == bare.centre_base_m


def test_a_centre_that_disagrees_with_the_transform_is_rejected() -> None:
    with pytest.raises(ConfigError, match="centre_base_m"):
        PinholeCamera(
            camera_id="c", fx_px=1.0, fy_px=1.0, cx_px=0.0, cy_px=0.0, width_px=4, height_px=4,
            camera_from_base=np.eye(4), centre_base_m=(0.0, 0.0, 1.0),
        )  # fmt: skip


def test_bad_calibration_is_rejected_with_the_field_named() -> None:
    with pytest.raises(ConfigError, match="camera_from_base"):
        PinholeCamera(
            camera_id="c", fx_px=1.0, fy_px=1.0, cx_px=0.0, cy_px=0.0, width_px=4, height_px=4,
            camera_from_base=np.eye(3),
        )  # fmt: skip
    with pytest.raises(ConfigError, match="pitch_rad"):
        PinholeCamera.mounted(
            "c", fx_px=1.0, fy_px=1.0, cx_px=0.0, cy_px=0.0, width_px=4, height_px=4, x_m=0.0, y_m=0.0,
            z_m=1.0, pitch_rad=math.nan,
        )  # fmt: skip


def test_calibration_arrays_are_read_only() -> None:
    with pytest.raises(ValueError):
        REAR.camera_from_base[0, 3] = 1.0
    with pytest.raises(ValueError):
        REAR.K[0, 0] = 1.0


@given(
    st.floats(-30.0, -2.0),
    st.floats(-10.0, 10.0),
    st.floats(-1.0, 4.0),
)
def test_both_projections_agree_for_points_in_front(x: float, y: float, z: float) -> None:
    uv, front = REAR.pixels_from_base([[x, y, z]])
    assert front.all()
    assert np.allclose(uv, REAR.pixels_from_camera(REAR.to_camera([[x, y, z]])), rtol=0.0, atol=1e-6)


def test_points_behind_the_camera_have_no_pixel() -> None:
    uv, front = REAR.pixels_from_base([[5.0, 0.0, 2.0], [-5.0, 0.0, 2.0]])
    assert front.tolist() == [False, True]
    assert np.isnan(uv[0]).all() and np.isfinite(uv[1]).all()
