"""The pinhole camera model: intrinsics K, mounting [R|t] on the vehicle, projection; the detector protocol.

Frames: the base frame is x forward, y left, z up (rear axle on the road); the camera frame is the
optical one, z along the optical axis, x right, y down in the image. ``camera_from_base`` maps base
points into the camera frame: p_cam = R @ p_base + t.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError
from lastmile.core.sensor_frames import CameraDetections
from lastmile.core.stamp import Stamp

# Base axes (x fwd, y left, z up) to optical axes (x right, y down, z fwd) for a camera looking ahead.
_OPTICAL_FROM_MOUNT = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
_OPTICAL_FROM_MOUNT.setflags(write=False)
OPTICAL_FROM_BODY = _OPTICAL_FROM_MOUNT
"""(3, 3) rotation from a camera's body frame (x along the optical axis, y left, z up: ROS's
``camera_link``) to its optical frame (x right, y down, z along the axis: ``camera_optical_frame``)."""


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class PinholeCamera:
    """An undistorted pinhole camera mounted on the vehicle: intrinsics K and the extrinsic [R|t].

    The one camera model of the project: the simulator's detectors render with it, perception fuses
    and verifies with it, tracking projects the map's traffic lights with it.

    Attributes:
        camera_id: the id carried by :class:`~lastmile.core.sensor_frames.CameraDetections` from it.
        fx_px, fy_px, cx_px, cy_px: intrinsics (pixels); K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]].
        width_px, height_px: image size; points projecting outside are out of view.
        camera_from_base: (4, 4) float64 rigid transform, base frame -> camera optical frame
            (p_cam = R @ p_base + t with R = [:3, :3], t = [:3, 3]); stored read-only.
        centre_base_m: optical centre (x, y, z) in the base frame. Derived from ``camera_from_base``
            (-R^T t) when not given; the mounting constructors pass the surveyed numbers, which are
            checked against the transform.
        min_depth_m: points nearer than this along the optical axis have no pixel in
            :meth:`pixels_from_base`.
    """

    camera_id: str
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int
    camera_from_base: np.ndarray
    centre_base_m: tuple[float, float, float] | None = None
    min_depth_m: float = 0.1
    K: np.ndarray = field(init=False, repr=False)
    """(3, 3) intrinsic matrix, read-only."""

    def __post_init__(self) -> None:
        for name in ("fx_px", "fy_px", "cx_px", "cy_px", "min_depth_m"):
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
        T = _checked_transform(self.camera_id, self.camera_from_base)
        centre = _checked_centre(self.camera_id, T, self.centre_base_m)
        K = np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])
        K.setflags(write=False)
        object.__setattr__(self, "camera_from_base", T)
        object.__setattr__(self, "centre_base_m", centre)
        object.__setattr__(self, "K", K)

    @staticmethod
    def mounted(
        camera_id: str, *, fx_px: float, fy_px: float, cx_px: float, cy_px: float, width_px: int,
        height_px: int, x_m: float, y_m: float, z_m: float, yaw_rad: float = 0.0, pitch_rad: float = 0.0,
    ) -> PinholeCamera:  # fmt: skip
        """A camera with its optical centre at (x, y, z) in the base frame, the optical axis turned
        ``yaw_rad`` from the base x axis (counter-clockwise; pi looks back) and tilted ``pitch_rad``
        below the horizon (positive looks down)."""
        for name, value in (
            ("x_m", x_m),
            ("y_m", y_m),
            ("z_m", z_m),
            ("yaw_rad", yaw_rad),
            ("pitch_rad", pitch_rad),
        ):
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ConfigError(
                    f"PinholeCamera {camera_id!r}.{name}: expected a finite number, got {value!r}"
                )
        cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
        cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # positive pitch: x tips down
        rot = _OPTICAL_FROM_MOUNT @ (rz @ ry).T
        T = np.eye(4)
        T[:3, :3] = rot
        T[:3, 3] = -rot @ np.array([x_m, y_m, z_m])
        return PinholeCamera(
            camera_id=camera_id, fx_px=fx_px, fy_px=fy_px, cx_px=cx_px, cy_px=cy_px, width_px=width_px,
            height_px=height_px, camera_from_base=T, centre_base_m=(x_m, y_m, z_m),
        )  # fmt: skip

    @staticmethod
    def from_fov(
        camera_id: str, width_px: int, height_px: int, hfov_deg: float, x_m: float, y_m: float, z_m: float,
        yaw_rad: float = 0.0, pitch_rad: float = 0.0,
    ) -> PinholeCamera:  # fmt: skip
        """Square pixels, principal point at the image centre, focal length from the horizontal FOV;
        mounted as in :meth:`mounted`."""
        if not 1.0 < hfov_deg < 179.0:
            raise ConfigError(f"PinholeCamera {camera_id!r}.hfov_deg: expected 1..179 deg, got {hfov_deg}")
        f = 0.5 * width_px / math.tan(math.radians(hfov_deg) / 2.0)
        return PinholeCamera.mounted(
            camera_id, fx_px=f, fy_px=f, cx_px=width_px / 2.0, cy_px=height_px / 2.0, width_px=width_px,
            height_px=height_px, x_m=x_m, y_m=y_m, z_m=z_m, yaw_rad=yaw_rad, pitch_rad=pitch_rad,
        )  # fmt: skip

    @property
    def x_m(self) -> float:
        """Optical centre x in the base frame."""
        return self._centre[0]

    @property
    def y_m(self) -> float:
        """Optical centre y in the base frame."""
        return self._centre[1]

    @property
    def z_m(self) -> float:
        """Optical centre z in the base frame."""
        return self._centre[2]

    @property
    def _centre(self) -> tuple[float, float, float]:
        assert self.centre_base_m is not None  # always set by __post_init__
        return self.centre_base_m

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) R of ``camera_from_base`` (a read-only view)."""
        return self.camera_from_base[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        """(3,) t of ``camera_from_base`` (a read-only view)."""
        return self.camera_from_base[:3, 3]

    def to_camera(self, points_base_m: npt.ArrayLike) -> np.ndarray:
        """(N, 3) base-frame points -> (N, 3) camera-frame points (z is the depth along the axis)."""
        p = np.asarray(points_base_m, dtype=np.float64).reshape(-1, 3)
        return p @ self.rotation.T + self.translation

    def pixels_from_camera(self, points_cam_m: npt.ArrayLike) -> np.ndarray:
        """(N, 3) camera-frame points with z > 0 -> (N, 2) pixel coordinates (u right, v down)."""
        p = np.asarray(points_cam_m, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        return np.column_stack([self.fx_px * p[:, 0] / z + self.cx_px, self.fy_px * p[:, 1] / z + self.cy_px])

    def pixels_from_base(self, points_base_m: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) of base-frame points and a (N,) mask of points in front of the camera
        (deeper than ``min_depth_m``); the pixels of the others are NaN.

        The pixels are K @ p divided by its third row; :meth:`pixels_from_camera` divides first. The two
        agree to rounding; each keeps the operations its callers were calibrated and tested with.
        """
        pc = self.to_camera(points_base_m)
        front = pc[:, 2] > self.min_depth_m
        uv = np.full((len(pc), 2), np.nan)
        h = pc[front] @ self.K.T
        uv[front] = h[:, :2] / h[:, 2:3]
        return uv, front

    def project_box(self, corners_base_m: npt.ArrayLike) -> np.ndarray | None:
        """Image box (u_min, v_min, u_max, v_max) of a 3D box's (8, 3) corners, clipped to the image.

        Returns None when any corner is behind the camera (a box straddling the image plane has no
        meaningful image extent) or the box falls entirely outside the image.
        """
        uv, front = self.pixels_from_base(corners_base_m)
        if not front.all():
            return None
        u0, v0 = uv.min(axis=0)
        u1, v1 = uv.max(axis=0)
        u0, u1 = max(u0, 0.0), min(u1, float(self.width_px))
        v0, v1 = max(v0, 0.0), min(v1, float(self.height_px))
        if u1 <= u0 or v1 <= v0:
            return None
        return np.array([u0, v0, u1, v1])


def _checked_transform(camera_id: str, camera_from_base: npt.ArrayLike) -> np.ndarray:
    """A read-only float64 copy of a finite (4, 4) rigid transform; ConfigError otherwise."""
    T = np.array(camera_from_base, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ConfigError(
            f"PinholeCamera {camera_id!r}.camera_from_base: expected a finite 4x4, got shape {T.shape}"
        )
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ConfigError(
            f"PinholeCamera {camera_id!r}.camera_from_base: expected a rotation in [:3, :3], got {R.tolist()}"
        )
    T.setflags(write=False)
    return T


def _checked_centre(
    camera_id: str, T: np.ndarray, centre: tuple[float, float, float] | None
) -> tuple[float, float, float]:
    """The optical centre -R^T t of ``T``, or ``centre`` when given and within 1 um of it."""
    derived = -T[:3, :3].T @ T[:3, 3]
    if centre is None:
        return (float(derived[0]), float(derived[1]), float(derived[2]))
    given = tuple(float(v) for v in centre)
    if len(given) != 3 or not np.allclose(given, derived, rtol=0.0, atol=1e-6):
        raise ConfigError(
            f"PinholeCamera {camera_id!r}.centre_base_m: expected the optical centre of camera_from_base "
            f"{derived.tolist()}, got {list(given)}"
        )
    return (given[0], given[1], given[2])


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
