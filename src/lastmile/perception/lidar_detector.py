"""A learned LiDAR 3D detector as a plug-in: an ONNX model on a bird's-eye-view raster.

Contract (checked when the model loads, :class:`~lastmile.perception.onnx_model.OnnxModel`):

- input ``bev``: float32 ``(1, C, H, W)``, the raster of :func:`lastmile.perception.bev_raster.bev_tensor`
  for the configured :class:`~lastmile.perception.bev_raster.BevGrid` (C channels in the listed order,
  H cells along x, W along y);
- output ``boxes``: float32 ``(1, K, 7)``, x, y, z (box centre), length, width, height (m) and yaw
  (rad, counter-clockwise from x) in the base frame, as :data:`lastmile.core.box3d.BOX3D_COLUMNS`;
- output ``scores``: float32 ``(1, K)``, in [0, 1];
- output ``classes``: int64 ``(1, K)``, :class:`~lastmile.core.object_class.ObjectClass` ids.

K may be any number (0 included). After the model: boxes under ``min_score`` are dropped, then
CenterPoint's circle NMS per class (a box whose centre lies within the class's radius of a
higher-scoring box of that class goes; radii of CenterPoint's nuScenes configuration).

The stack merges the detections with the clustering's objects (:func:`merge_with_clusters`): a
learned detector finds only the classes it was trained on, so by default every cluster that no
detection covers stays an (unclassified) object: a goose or a fallen barrel is never lost because
the model has no class for it. ``replace_clusters`` trusts the model alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np

from lastmile.core.box3d import BOX3D_COLUMNS
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.object_class import ObjectClass
from lastmile.perception.bev_raster import BevGrid, bev_tensor
from lastmile.perception.cluster_geometry import CLUSTER_COLUMNS, ClusterKind, ClusterSet
from lastmile.perception.onnx_model import OnnxModel, TensorSpec, check_detections
from lastmile.perception.pipeline import LidarPipelineResult

CIRCLE_NMS_RADIUS_M = {
    ObjectClass.CAR: 4.0,
    ObjectClass.CYCLIST: 0.85,
    ObjectClass.PEDESTRIAN: 0.175,
    ObjectClass.ANIMAL: 0.175,
    ObjectClass.UNKNOWN: 1.0,
}
"""CenterPoint's nuScenes ``min_radius`` per task: car 4, motorcycle/bicycle 0.85, pedestrian/cone
0.175, barrier 1 (for our unclassified objects); an animal is pedestrian-sized."""


class DetectorPoints(StrEnum):
    """Which of the merged cloud's points are rasterised."""

    ALL = "all"
    """Every point after the crop (as detectors trained on raw sweeps expect)."""
    NON_GROUND = "non_ground"
    """The pipeline's non-ground, non-noise points (for models trained on ground-removed clouds)."""


class DetectorMerge(StrEnum):
    """How the detections and the clustering's objects are combined."""

    WITH_CLUSTERS = "with_clusters"
    """Detections replace the clusters they cover; the other clusters stay, unclassified."""
    REPLACE_CLUSTERS = "replace_clusters"
    """The detections alone."""


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarDetectorConfig:
    """Attributes:
    model: path of the ``.onnx`` file.
    grid: the BEV raster the model takes (extent, cell, channels).
    points: which points are rasterised.
    merge: how detections and clusters combine.
    min_score: detections below this score are dropped (CenterPoint's test threshold, 0.1).
    circle_nms: apply CenterPoint's per-class circle NMS after the model.
    """

    model: str
    grid: BevGrid = field(default_factory=BevGrid)
    points: DetectorPoints = DetectorPoints.ALL
    merge: DetectorMerge = DetectorMerge.WITH_CLUSTERS
    min_score: float = 0.1
    circle_nms: bool = True

    def __post_init__(self) -> None:
        if not self.model:
            raise ConfigError("LidarDetectorConfig.model: expected the path of an .onnx file, got ''")
        if not (math.isfinite(self.min_score) and 0.0 <= self.min_score <= 1.0):
            raise ConfigError(f"LidarDetectorConfig.min_score: expected 0..1, got {self.min_score}")


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarDetections:
    """One frame's detections in the base frame.

    Attributes:
        boxes: (K, 7) float64, :data:`BOX3D_COLUMNS`.
        scores: (K,) float64.
        class_id: (K,) int64 :class:`ObjectClass` ids.
    """

    boxes: np.ndarray
    scores: np.ndarray
    class_id: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)


def lidar_detector_contract(grid: BevGrid) -> tuple[tuple[TensorSpec, ...], tuple[TensorSpec, ...]]:
    """The model's inputs and outputs for ``grid``."""
    f32, i64 = np.dtype(np.float32), np.dtype(np.int64)
    inputs = (TensorSpec(name="bev", dtype=f32, shape=grid.shape),)
    outputs = (
        TensorSpec(name="boxes", dtype=f32, shape=(1, None, len(BOX3D_COLUMNS))),
        TensorSpec(name="scores", dtype=f32, shape=(1, None)),
        TensorSpec(name="classes", dtype=i64, shape=(1, None)),
    )
    return inputs, outputs


class OnnxLidarDetector:
    """Runs the configured model on a cloud; see the module docstring for the contract.

    Raises:
        ConfigError: at construction, when the model cannot be loaded or breaks the contract.
    """

    def __init__(self, config: LidarDetectorConfig) -> None:
        self.config = config
        inputs, outputs = lidar_detector_contract(config.grid)
        self.model = OnnxModel(Path(config.model), inputs, outputs, "LiDAR detector")

    def detect(self, xyz_m: np.ndarray, intensity: np.ndarray) -> LidarDetections:
        """Detections from (N, 3) base-frame points and their (N,) 0..255 intensities.

        Raises:
            MessageError: malformed points, or a model output that breaks the contract (counts that
                disagree, non-finite boxes, negative sizes, scores outside [0, 1], unknown classes).
        """
        out = self.model.run({"bev": bev_tensor(xyz_m, intensity, self.config.grid)})
        boxes = out["boxes"][0].astype(np.float64)
        scores = out["scores"][0].astype(np.float64)
        cls = out["classes"][0]
        self._check(boxes, scores, cls)
        keep = scores >= self.config.min_score
        boxes, scores, cls = boxes[keep], scores[keep], cls[keep]
        if self.config.circle_nms:
            kept = circle_nms(boxes[:, :2], scores, cls)
            boxes, scores, cls = boxes[kept], scores[kept], cls[kept]
        return LidarDetections(boxes=boxes, scores=scores, class_id=cls.astype(np.int64))

    def _check(self, boxes: np.ndarray, scores: np.ndarray, cls: np.ndarray) -> None:
        where = f"LiDAR detector model {self.model.path}"
        check_detections(where, boxes, scores, cls)
        if (boxes[:, 3:6] <= 0).any():
            raise MessageError(f"{where}: expected positive box sizes, got {boxes[:, 3:6].min():.3g}")


def circle_nms(xy_m: np.ndarray, scores: np.ndarray, class_id: np.ndarray) -> np.ndarray:
    """Indices kept by CenterPoint's circle NMS, per class, in descending score (ties: first wins)."""
    order = np.argsort(-scores, kind="stable")
    kept: list[int] = []
    for i in order:
        radius = CIRCLE_NMS_RADIUS_M[ObjectClass(int(class_id[i]))]
        same = [k for k in kept if class_id[k] == class_id[i]]
        if same and np.hypot(*(xy_m[same] - xy_m[i]).T).min() <= radius:
            continue
        kept.append(int(i))
    return np.array(sorted(kept), dtype=np.int64)


def _inside(px: np.ndarray, py: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(P, B) whether each point lies in each box's footprint (rows x, y, ..., l, w, ..., yaw)."""
    dx = px[:, None] - boxes[None, :, 0]
    dy = py[:, None] - boxes[None, :, 1]
    c, s = np.cos(boxes[:, 6]), np.sin(boxes[:, 6])
    u, v = c * dx + s * dy, -s * dx + c * dy
    return (np.abs(u) <= boxes[:, 3] / 2) & (np.abs(v) <= boxes[:, 4] / 2)


@dataclass(frozen=True, slots=True, kw_only=True)
class MergedObjects:
    """:func:`merge_with_clusters` output: a cluster set for late fusion and each row's prior.

    Attributes:
        clusters: the kept clusters, then one row per detection (its box; ``n_points`` and
            ``mean_intensity`` 0, ``confidence`` its score).
        class_id: (K,) int64 class per row (UNKNOWN for clusters).
        score: (K,) float64 score per row (0 for clusters: late fusion gives its own).
        from_detector: (K,) bool, the row is a detection.
        replaced_clusters: how many clusters a detection covered.
    """

    clusters: ClusterSet
    class_id: np.ndarray
    score: np.ndarray
    from_detector: np.ndarray
    replaced_clusters: int


def merge_with_clusters(clusters: ClusterSet, det: LidarDetections, merge: DetectorMerge) -> MergedObjects:
    """Combine the clustering's objects and the detector's (both in the base frame).

    A cluster is covered by a detection when the cluster's centre lies in the detection's footprint
    or the detection's centre in the cluster's box.
    """
    t = clusters.table
    if merge is DetectorMerge.REPLACE_CLUSTERS:
        keep = np.zeros(len(t), dtype=bool)
    elif len(det) and len(t):
        cluster_boxes = t[:, [0, 1, 2, 4, 5, 3, 6]]  # only x, y, length, width, yaw are read
        covered = _inside(t[:, 0], t[:, 1], det.boxes).any(axis=1) | _inside(
            det.boxes[:, 0], det.boxes[:, 1], cluster_boxes
        ).any(axis=0)
        keep = np.asarray(~covered, dtype=bool)
    else:
        keep = np.ones(len(t), dtype=bool)
    b = det.boxes
    rows = np.zeros((len(b), len(CLUSTER_COLUMNS)))
    col = {n: i for i, n in enumerate(CLUSTER_COLUMNS)}
    rows[:, col["x_m"]], rows[:, col["y_m"]] = b[:, 0], b[:, 1]
    rows[:, col["z_min_m"]], rows[:, col["z_max_m"]] = b[:, 2] - b[:, 5] / 2, b[:, 2] + b[:, 5] / 2
    rows[:, col["length_m"]], rows[:, col["width_m"]], rows[:, col["yaw_rad"]] = b[:, 3], b[:, 4], b[:, 6]
    rows[:, col["range_m"]] = np.hypot(b[:, 0], b[:, 1])
    rows[:, col["kind"]] = int(ClusterKind.OTHER)
    rows[:, col["confidence"]] = det.scores
    D = clusters.hull_xy.shape[1]
    hull = np.zeros((len(b), D, 2))
    hull_new = np.zeros((len(b), D), dtype=bool)
    for k in range(len(b)):
        corners = _footprint(b[k])
        hull[k, :4], hull[k, 4:] = corners, corners[-1]
        hull_new[k, :4] = True
    merged = ClusterSet(
        table=np.vstack([t[keep], rows]),
        hull_xy=np.concatenate([clusters.hull_xy[keep], hull]),
        hull_new=np.concatenate([clusters.hull_new[keep], hull_new]),
        labels=np.concatenate([clusters.labels[keep], np.full(len(b), -1, dtype=np.int64)]),
    )
    n_kept = int(keep.sum())
    return MergedObjects(
        clusters=merged,
        class_id=np.concatenate([np.full(n_kept, int(ObjectClass.UNKNOWN)), det.class_id]).astype(np.int64),
        score=np.concatenate([np.zeros(n_kept), det.scores]),
        from_detector=np.concatenate([np.zeros(n_kept, dtype=bool), np.ones(len(b), dtype=bool)]),
        replaced_clusters=len(t) - n_kept,
    )


def clusters_only(clusters: ClusterSet) -> MergedObjects:
    """The clustering's objects alone, as :func:`merge_with_clusters` would give them (no detector)."""
    n = len(clusters)
    return MergedObjects(
        clusters=clusters,
        class_id=np.full(n, int(ObjectClass.UNKNOWN), dtype=np.int64),
        score=np.zeros(n),
        from_detector=np.zeros(n, dtype=bool),
        replaced_clusters=0,
    )


def frame_objects(
    result: LidarPipelineResult, detector: OnnxLidarDetector | None
) -> tuple[MergedObjects, int]:
    """One frame's objects: the pipeline's clusters, with ``detector``'s boxes merged in when given
    (its configured points rasterised); also how many detections the model gave."""
    if detector is None:
        return clusters_only(result.clusters), 0
    cfg = detector.config
    pts = result.cloud.points
    if cfg.points is DetectorPoints.NON_GROUND:
        pts = pts[~(result.ground | result.noise)]
    det = detector.detect(pts[:, 0:3], pts[:, 3])
    return merge_with_clusters(result.clusters, det, cfg.merge), len(det)


def _footprint(box: np.ndarray) -> np.ndarray:
    """(4, 2) footprint corners of one box, counter-clockwise."""
    c, s = math.cos(box[6]), math.sin(box[6])
    half = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * (box[3] / 2, box[4] / 2)
    return box[:2] + half @ np.array([[c, s], [-s, c]])
