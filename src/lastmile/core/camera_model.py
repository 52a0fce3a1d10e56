"""Pinhole cameras: intrinsics K, the mounting [R|t] on the vehicle, projection; the detector protocol.

Frames: the base frame is x forward, y left, z up (rear axle on the road); the camera frame is the
optical one, z along the optical axis, x right, y down in the image. ``camera_from_base`` maps base
points into the camera frame: p_cam = R @ p_base + t.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.sensor_frames import CameraDetections
from lastmile.core.stamp import Stamp

# Base axes (x fwd, y left, z up) to optical axes (x right, y down, z fwd) for a camera looking ahead.
_OPTICAL_FROM_MOUNT = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True, slots=True, kw_only=True)
class PinholeCamera:
    """An undistorted pinhole camera mounted on the vehicle.

    Attributes:
        fx_px, fy_px, cx_px, cy_px: intrinsics (pixels); K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]].
        width_px, height_px: image size.
        x_m, y_m, z_m: optical centre in the base frame.
        yaw_rad: heading of the optical axis from the base x axis (counter-clockwise; pi looks back).
        pitch_rad: tilt of the optical axis below the horizon (positive looks down).
    """

    camera_id: str
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float = 0.0
    pitch_rad: float = 0.0

    def __post_init__(self) -> None:
        for name in ("fx_px", "fy_px", "cx_px", "cy_px", "x_m", "y_m", "z_m", "yaw_rad", "pitch_rad"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ConfigError(
                    f"PinholeCamera {self.camera_id!r}.{name}: expected a finite number, got {value!r}"
                )
        if self.fx_px <= 0 or self.fy_px <= 0 or self.width_px <= 0 or self.height_px <= 0:
            raise ConfigError(
                f"PinholeCamera {self.camera_id!r}: expected positive focal lengths and image size, got "
                f"f=({self.fx_px}, {self.fy_px}), size=({self.width_px}, {self.height_px})"
            )

    @staticmethod
    def from_fov(
        camera_id: str, width_px: int, height_px: int, hfov_deg: float, x_m: float, y_m: float, z_m: float,
        yaw_rad: float = 0.0, pitch_rad: float = 0.0,
    ) -> PinholeCamera:  # fmt: skip
        """Square pixels, principal point at the image centre, focal length from the horizontal FOV."""
        if not 1.0 < hfov_deg < 179.0:
            raise ConfigError(f"PinholeCamera {camera_id!r}.hfov_deg: expected 1..179 deg, got {hfov_deg}")
        f = 0.5 * width_px / math.tan(math.radians(hfov_deg) / 2.0)
        return PinholeCamera(
            camera_id=camera_id, fx_px=f, fy_px=f, cx_px=width_px / 2.0, cy_px=height_px / 2.0,
            width_px=width_px, height_px=height_px, x_m=x_m, y_m=y_m, z_m=z_m, yaw_rad=yaw_rad,
            pitch_rad=pitch_rad,
        )  # fmt: skip

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the matrix's usual name
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    def camera_from_base(self) -> tuple[np.ndarray, np.ndarray]:
        """(R (3, 3), t (3,)) with p_cam = R @ p_base + t."""
        cy, sy = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        cp, sp = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # positive pitch: x tips down
        rot = _OPTICAL_FROM_MOUNT @ (rz @ ry).T
        return rot, -rot @ np.array([self.x_m, self.y_m, self.z_m])

    def to_camera(self, points_base_m: np.ndarray) -> np.ndarray:
        """(N, 3) base-frame points -> (N, 3) camera-frame points (z is the depth along the axis)."""
        rot, t = self.camera_from_base()
        return np.asarray(points_base_m, dtype=np.float64).reshape(-1, 3) @ rot.T + t

    def project(self, points_cam_m: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points with z > 0 -> (N, 2) pixel coordinates (u right, v down)."""
        p = np.asarray(points_cam_m, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        return np.column_stack([self.fx_px * p[:, 0] / z + self.cx_px, self.fy_px * p[:, 1] / z + self.cy_px])


class CameraDetector(Protocol):
    """Anything that turns one camera observation into 2D boxes.

    The simulator's model-free detector takes a scene description; a real network (for example an
    ONNX YOLO) takes the image. Both return :class:`CameraDetections` with class ids of
    :class:`lastmile.core.object_class.ObjectClass`, so consumers do not change when one replaces
    the other.
    """

    camera_id: str

    def detect(self, observation: Any, stamp: Stamp) -> CameraDetections:
        """Boxes found in ``observation`` captured at ``stamp``."""
        ...
