"""NUS's pedestrian verification (section III): LiDAR candidates checked against the camera.

Phase 1, candidate detector: clusters whose size fits a person (relaxed on purpose: false
candidates are cheap, missed ones are not). Phase 2, verification: each candidate's 3D box is
projected into the camera with K and [R|t]; it is verified when a camera pedestrian detection
overlaps its image box well enough. Candidates outside the camera's view stay unverified but are
still reported (NUS: they are tracked as generic dynamic objects and avoided).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.sensor_frames import CAMERA_BOX_COLUMNS, CameraDetections
from lastmile.perception.camera_geometry import box_corners_3d, box_iou
from lastmile.perception.cluster_geometry import ClusterSet


@dataclass(frozen=True, slots=True, kw_only=True)
class PedestrianVerificationConfig:
    """Attributes:
    min_height_m, max_height_m: candidate height span.
    max_footprint_m: candidate's longer horizontal side.
    min_iou: image-box overlap that verifies a candidate.
    min_score: camera detections below this score are ignored.
    """

    min_height_m: float = 0.8
    max_height_m: float = 2.3
    max_footprint_m: float = 1.5
    min_iou: float = 0.3
    min_score: float = 0.3

    def __post_init__(self) -> None:
        if not (0 < self.min_height_m < self.max_height_m and self.max_footprint_m > 0):
            raise ConfigError(f"PedestrianVerificationConfig: expected 0 < min < max height, got {self}")
        if not (0 < self.min_iou <= 1 and 0 <= self.min_score <= 1):
            raise ConfigError(
                f"PedestrianVerificationConfig: expected min_iou in (0, 1], score in [0, 1], got {self}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class VerifiedPedestrians:
    """Attributes:
    rows: (K,) int64 cluster-set rows of the candidates.
    in_view: (K,) bool, the candidate projects into the image.
    verified: (K,) bool, a camera pedestrian box confirms it.
    image_boxes: (K, 4) float64 projected boxes (NaN where not in view).
    """

    rows: np.ndarray
    in_view: np.ndarray
    verified: np.ndarray
    image_boxes: np.ndarray


def pedestrian_candidates(
    clusters: ClusterSet, config: PedestrianVerificationConfig | None = None
) -> np.ndarray:
    """(K,) rows of clusters shaped like a standing person."""
    cfg = config or PedestrianVerificationConfig()
    h = clusters.col("z_max_m") - clusters.col("z_min_m")
    ok = (h >= cfg.min_height_m) & (h <= cfg.max_height_m) & (clusters.col("length_m") <= cfg.max_footprint_m)
    ok &= clusters.col("z_min_m") < 0.5  # standing on the ground, not a sign plate
    return np.flatnonzero(ok).astype(np.int64)


def verify_pedestrians(
    clusters: ClusterSet,
    camera: PinholeCamera,
    detections: CameraDetections,
    config: PedestrianVerificationConfig | None = None,
) -> VerifiedPedestrians:
    """Project every candidate into ``camera`` and verify it against its pedestrian boxes."""
    cfg = config or PedestrianVerificationConfig()
    if detections.camera_id != camera.camera_id:
        raise ConfigError(
            f"verify_pedestrians: expected detections from camera {camera.camera_id!r}, "
            f"got {detections.camera_id!r}"
        )
    rows = pedestrian_candidates(clusters, cfg)
    boxes = np.full((len(rows), 4), np.nan)
    for i, r in enumerate(rows):
        t = clusters.table[r]
        corners = box_corners_3d(t[0], t[1], t[2], t[3], max(t[4], 0.2), max(t[5], 0.2), t[6])
        b = camera.project_box(corners)
        if b is not None:
            boxes[i] = b
    in_view = np.isfinite(boxes).all(axis=1)
    cls = CAMERA_BOX_COLUMNS.index("class_id")
    score = CAMERA_BOX_COLUMNS.index("score")
    det = detections.boxes
    ped = det[(det[:, cls] == int(ObjectClass.PEDESTRIAN)) & (det[:, score] >= cfg.min_score), :4]
    verified = np.zeros(len(rows), dtype=bool)
    if len(ped) and in_view.any():
        iou = box_iou(boxes[in_view], ped)
        verified[in_view] = iou.max(axis=1) >= cfg.min_iou
    return VerifiedPedestrians(rows=rows, in_view=in_view, verified=verified, image_boxes=boxes)
