"""Per-track class estimation by a hidden Markov model (aUToronto 6.3), and camera evidence by projection.

The hidden state is the object's true class (one of :class:`ObjectClass`). Between updates it may
change with probability ``switch_prob`` (spread evenly over the other classes): this keeps the filter
able to recover from a wrong early guess. An observation "class j" from a source with accuracy ``a``
has likelihood ``a`` under true class j and ``(1 - a) / (C - 1)`` under any other. LiDAR boxes and
2D camera detections matched to a track through projection are both observations; camera
detections change the class only, never the kinematic state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from lastmile.core.box3d import BOX3D_COLUMNS
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.object_class import ObjectClass

N_CLASSES = len(ObjectClass)


@dataclass(frozen=True, slots=True, kw_only=True)
class ClassHmmConfig:
    """Parameters of the class HMM (probabilities, dimensionless).

    Attributes:
        switch_prob: probability that the true class changes between two updates.
        lidar_accuracy: probability a 3D detector reports the true class.
        camera_accuracy: probability a 2D camera detector reports the true class.
        min_camera_iou: smallest image IoU between a projected track and a camera box to match.
    """

    switch_prob: float = 0.01
    lidar_accuracy: float = 0.85
    camera_accuracy: float = 0.9
    min_camera_iou: float = 0.3

    def __post_init__(self) -> None:
        if not 0.0 <= self.switch_prob < 1.0:
            raise ConfigError(f"ClassHmmConfig.switch_prob: expected in [0, 1), got {self.switch_prob}")
        for name in ("lidar_accuracy", "camera_accuracy"):
            v = getattr(self, name)
            if not 1.0 / N_CLASSES < v < 1.0:
                raise ConfigError(f"ClassHmmConfig.{name}: expected in (1/{N_CLASSES}, 1), got {v}")
        if not 0.0 < self.min_camera_iou <= 1.0:
            raise ConfigError(f"ClassHmmConfig.min_camera_iou: expected in (0, 1], got {self.min_camera_iou}")


def initial_prob(class_id: np.ndarray, accuracy: float) -> np.ndarray:
    """Posterior after one observation from a uniform prior, (N, C)."""
    n = class_id.shape[0]
    p = np.full((n, N_CLASSES), (1.0 - accuracy) / (N_CLASSES - 1))
    p[np.arange(n), class_id] = accuracy
    return p


def hmm_update(prob: np.ndarray, observed: np.ndarray, accuracy: float, switch_prob: float) -> np.ndarray:
    """One HMM step (transition, then observation) for each row; returns the new posteriors.

    Args:
        prob: (N, C) current posteriors.
        observed: (N,) observed class index per row.
        accuracy: the source's probability of reporting the true class.
        switch_prob: class change probability per step.
    """
    stay = 1.0 - switch_prob
    pred = stay * prob + switch_prob * (1.0 - prob) / (N_CLASSES - 1)
    like = np.full_like(pred, (1.0 - accuracy) / (N_CLASSES - 1))
    like[np.arange(prob.shape[0]), observed] = accuracy
    post = pred * like
    return post / post.sum(axis=1, keepdims=True)


def project_boxes(boxes: np.ndarray, camera_from_frame: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Image boxes ``(x1, y1, x2, y2)`` of 3D boxes seen by a pinhole camera; NaN rows when behind it.

    Args:
        boxes: (N, 7) :data:`BOX3D_COLUMNS` in the tracker's frame.
        camera_from_frame: (4, 4) transform into the camera's optical frame (z forward, x right, y down).
        intrinsics: (3, 3) camera matrix.
    """
    if camera_from_frame.shape != (4, 4) or intrinsics.shape != (3, 3):
        raise MessageError(
            "project_boxes: expected (4, 4) and (3, 3) matrices, "
            f"got {camera_from_frame.shape}, {intrinsics.shape}"
        )
    n = boxes.shape[0]
    if n == 0:
        return np.zeros((0, 4))
    c, s = np.cos(boxes[:, 6]), np.sin(boxes[:, 6])
    sx = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * 0.5
    sy = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * 0.5
    sz = np.array([1, 1, 1, 1, -1, -1, -1, -1]) * 0.5
    lx, ly = sx[None] * boxes[:, 3:4], sy[None] * boxes[:, 4:5]
    pts = np.stack(
        [
            boxes[:, 0:1] + c[:, None] * lx - s[:, None] * ly,
            boxes[:, 1:2] + s[:, None] * lx + c[:, None] * ly,
            boxes[:, 2:3] + sz[None] * boxes[:, 5:6],
            np.ones((n, 8)),
        ],
        axis=-1,
    )  # (N, 8, 4)
    cam = pts @ camera_from_frame.T
    behind = np.any(cam[..., 2] <= 0.1, axis=1)
    uvw = cam[..., :3] @ intrinsics.T
    z = np.where(uvw[..., 2:3] > 0.1, uvw[..., 2:3], 1.0)
    uv = uvw[..., :2] / z
    out = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
    out[behind] = np.nan
    return out


def image_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) IoU of image boxes; 0 where a row of ``a`` is NaN."""
    x1 = np.maximum(a[:, None, 0], b[None, :, 0])
    y1 = np.maximum(a[:, None, 1], b[None, :, 1])
    x2 = np.minimum(a[:, None, 2], b[None, :, 2])
    y2 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
    return np.nan_to_num(iou, nan=0.0)


def match_camera_detections(
    track_boxes: np.ndarray,
    camera_boxes: np.ndarray,
    camera_from_frame: np.ndarray,
    intrinsics: np.ndarray,
    min_iou: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Match 2D camera boxes to tracks by projecting the tracks; (track index, camera box index) pairs."""
    if track_boxes.shape[1:] != (len(BOX3D_COLUMNS),) or camera_boxes.ndim != 2 or camera_boxes.shape[1] != 4:
        raise MessageError(
            f"match_camera_detections: expected (T, 7) tracks and (M, 4) image boxes, "
            f"got {track_boxes.shape} and {camera_boxes.shape}"
        )
    if track_boxes.shape[0] == 0 or camera_boxes.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    iou = image_iou(project_boxes(track_boxes, camera_from_frame, intrinsics), camera_boxes)
    r, c = linear_sum_assignment(-iou)
    ok = iou[r, c] >= min_iou
    return r[ok].astype(np.int64), c[ok].astype(np.int64)
