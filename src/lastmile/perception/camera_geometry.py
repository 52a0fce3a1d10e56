"""Image-box geometry for camera fusion: 3D box corners and image-box IoU.

The camera model itself (K, ``camera_from_base``, projection) is
:class:`lastmile.core.camera_model.PinholeCamera`, shared with the simulator and tracking.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


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
