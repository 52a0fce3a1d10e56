"""Pinhole camera geometry: project base-frame points into an image with K and [R|t].

Camera frame convention (OpenCV, as KITTI and most detectors use): x right, y down, z forward along
the optical axis. ``camera_from_base`` is the 4x4 homogeneous transform [R|t] taking base-frame points
(x forward, y left, z up) into the camera frame; ``K`` is the 3x3 intrinsic matrix in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lastmile.core.camera_model import PinholeCamera as CameraModel
from lastmile.core.errors import MessageError

FloatArray = npt.NDArray[np.float64]

# Base (x fwd, y left, z up) -> camera optical (x right, y down, z fwd) for a camera looking along +x.
OPTICAL_FROM_FORWARD = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True, slots=True, kw_only=True)
class PinholeCamera:
    """A calibrated camera.

    Attributes:
        camera_id: the id carried by :class:`core.sensor_frames.CameraDetections` from this camera.
        K: (3, 3) float64 intrinsics (fx, fy, cx, cy in pixels).
        camera_from_base: (4, 4) float64 rigid transform, base frame -> camera optical frame.
        width_px, height_px: image size; points projecting outside are out of view.
        min_depth_m: points nearer than this along the optical axis are not projected.
    """

    camera_id: str
    K: FloatArray
    camera_from_base: FloatArray
    width_px: int
    height_px: int
    min_depth_m: float = 0.1

    def __post_init__(self) -> None:
        K = np.array(self.K, dtype=np.float64)
        T = np.array(self.camera_from_base, dtype=np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise MessageError(f"PinholeCamera.K: expected a finite 3x3 with fx, fy > 0, got {K.tolist()}")
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise MessageError(f"PinholeCamera.camera_from_base: expected a finite 4x4, got shape {T.shape}")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise MessageError(
                "PinholeCamera.camera_from_base: expected a rotation in [:3, :3], got a non-rotation"
            )
        if self.width_px <= 0 or self.height_px <= 0:
            raise MessageError(
                f"PinholeCamera: expected a positive image size, got {self.width_px}x{self.height_px}"
            )
        K.setflags(write=False)
        T.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "camera_from_base", T)

    @staticmethod
    def from_model(camera: CameraModel) -> PinholeCamera:
        """The same calibration as a :class:`lastmile.core.camera_model.PinholeCamera` (the sensor's)."""
        R, t = camera.camera_from_base()
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = t
        return PinholeCamera(
            camera_id=camera.camera_id,
            K=camera.K,
            camera_from_base=T,
            width_px=camera.width_px,
            height_px=camera.height_px,
        )

    @staticmethod
    def looking_forward(
        camera_id: str,
        *,
        fx_px: float,
        width_px: int,
        height_px: int,
        x_m: float,
        y_m: float,
        z_m: float,
        yaw_rad: float = 0.0,
    ) -> PinholeCamera:
        """A level camera at (x, y, z) in the base frame whose optical axis points at ``yaw_rad``."""
        c, s = np.cos(yaw_rad), np.sin(yaw_rad)
        base_from_cam_fwd = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        R = OPTICAL_FROM_FORWARD @ base_from_cam_fwd.T
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = -R @ np.array([x_m, y_m, z_m])
        K = np.array([[fx_px, 0.0, width_px / 2.0], [0.0, fx_px, height_px / 2.0], [0.0, 0.0, 1.0]])
        return PinholeCamera(
            camera_id=camera_id, K=K, camera_from_base=T, width_px=width_px, height_px=height_px
        )

    def to_camera(self, xyz_base_m: npt.ArrayLike) -> FloatArray:
        """(N, 3) base-frame points -> (N, 3) camera optical-frame points."""
        p = np.asarray(xyz_base_m, dtype=np.float64).reshape(-1, 3)
        return p @ self.camera_from_base[:3, :3].T + self.camera_from_base[:3, 3]

    def project(self, xyz_base_m: npt.ArrayLike) -> tuple[FloatArray, np.ndarray]:
        """Pixel coordinates (N, 2) of base-frame points and a (N,) mask of points in front of the camera.

        Pixels of points behind ``min_depth_m`` are NaN.
        """
        pc = self.to_camera(xyz_base_m)
        front = pc[:, 2] > self.min_depth_m
        uv = np.full((len(pc), 2), np.nan)
        h = pc[front] @ self.K.T
        uv[front] = h[:, :2] / h[:, 2:3]
        return uv, front

    def project_box(self, corners_base_m: npt.ArrayLike) -> FloatArray | None:
        """Image box (u_min, v_min, u_max, v_max) of a 3D box's (8, 3) corners, clipped to the image.

        Returns None when any corner is behind the camera (a box straddling the image plane has no
        meaningful image extent) or the box falls entirely outside the image.
        """
        uv, front = self.project(corners_base_m)
        if not front.all():
            return None
        u0, v0 = uv.min(axis=0)
        u1, v1 = uv.max(axis=0)
        u0, u1 = max(u0, 0.0), min(u1, float(self.width_px))
        v0, v1 = max(v0, 0.0), min(v1, float(self.height_px))
        if u1 <= u0 or v1 <= v0:
            return None
        return np.array([u0, v0, u1, v1])


def box_corners_3d(
    x_m: float, y_m: float, z_min_m: float, z_max_m: float, length_m: float, width_m: float, yaw_rad: float
) -> FloatArray:
    """(8, 3) corners of an upright oriented box centred at (x, y) spanning z_min..z_max."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    hl, hw = length_m / 2.0, width_m / 2.0
    local = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])
    xy = local @ np.array([[c, s], [-s, c]]) + np.array([x_m, y_m])
    return np.vstack([np.c_[xy, np.full(4, z_min_m)], np.c_[xy, np.full(4, z_max_m)]])


def box_iou(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """(N, M) intersection over union of image boxes a (N, 4) and b (M, 4), columns u0, v0, u1, v1."""
    A = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    B = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    iw = np.clip(np.minimum(A[:, None, 2], B[None, :, 2]) - np.maximum(A[:, None, 0], B[None, :, 0]), 0, None)
    ih = np.clip(np.minimum(A[:, None, 3], B[None, :, 3]) - np.maximum(A[:, None, 1], B[None, :, 1]), 0, None)
    inter = iw * ih
    area_a = (A[:, 2] - A[:, 0]) * (A[:, 3] - A[:, 1])
    area_b = (B[:, 2] - B[:, 0]) * (B[:, 3] - B[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
