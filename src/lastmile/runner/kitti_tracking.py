"""Run aUToTrack on KITTI tracking detections and score it with the KITTI 3D MOT evaluator.

KITTI tracking runs at 10 Hz; frame k is stamped ``k * 100 ms``. The three PointRCNN detection files
of a sequence (``pointrcnn_<Class>/<seq>.txt``) feed one tracker (classes separated by the class term
of the association cost and the class HMM). Boxes are in the KITTI camera frame turned z-up (no ego
motion compensation: the data has no poses). Each detection's image box and observation angle ride
along as attributes so the results file carries them, as the KITTI format requires.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.core.box3d import kitti_camera_from_boxes
from lastmile.core.boxes3d import DetectedBoxes
from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.evaluation.kitti_io import CLASSES, KittiRows, read_detections, read_labels
from lastmile.evaluation.kitti_mot import ClassResult, evaluate_class
from lastmile.tracking.autotrack import AutoTrack, AutoTrackConfig

FRAME_US = 100_000
KITTI_TO_CLASS = {
    "Car": ObjectClass.CAR,
    "Pedestrian": ObjectClass.PEDESTRIAN,
    "Cyclist": ObjectClass.CYCLIST,
}
CLASS_TO_KITTI = {int(v): k for k, v in KITTI_TO_CLASS.items()}


@dataclass(frozen=True, slots=True, kw_only=True)
class SequenceFrames:
    """One sequence's detections, split per frame, ready to feed the tracker."""

    name: str
    n_frames: int
    messages: list[DetectedBoxes]


def load_sequence(detections_dir: Path, seq: str, n_frames: int | None = None) -> SequenceFrames:
    """Read the three classes' detections of ``seq`` into one :class:`DetectedBoxes` per frame.

    Raises:
        ConfigError: the detections directory or a class's file is missing.
        MessageError: a malformed line.
    """
    if not detections_dir.is_dir():
        raise ConfigError(
            "detections: expected a directory holding pointrcnn_<Class>/, "
            f"got {str(detections_dir)!r} (missing)"
        )
    parts = [read_detections(detections_dir / f"pointrcnn_{c}" / f"{seq}.txt") for c in CLASSES]
    frame = np.concatenate([p.frame for p in parts])
    boxes = np.concatenate([p.boxes() for p in parts])
    cls = np.concatenate([[int(KITTI_TO_CLASS[str(t)]) for t in p.obj_type] for p in parts]).astype(np.int64)
    score = np.concatenate([p.score for p in parts])
    attrs = np.concatenate([np.column_stack([p.image_box, p.alpha_rad]) for p in parts]).reshape(-1, 5)
    last = int(frame.max()) + 1 if frame.size else 0
    nf = max(n_frames or 0, last)
    order = np.argsort(frame, kind="stable")
    frame, boxes, cls, score, attrs = frame[order], boxes[order], cls[order], score[order], attrs[order]
    bounds = np.searchsorted(frame, np.arange(nf + 1))
    msgs = []
    for f in range(nf):
        a, b = bounds[f], bounds[f + 1]
        n = b - a
        msgs.append(
            DetectedBoxes(
                stamp=Stamp(f * FRAME_US),
                frame="kitti_camera_ground",
                source="pointrcnn",
                boxes=boxes[a:b],
                class_id=cls[a:b],
                score=score[a:b],
                velocity_mps=np.zeros((n, 2)),
                has_velocity=np.zeros(n, bool),
                attributes=attrs[a:b],
            )
        )
    return SequenceFrames(name=seq, n_frames=nf, messages=msgs)


def track_sequence(seq: SequenceFrames, config: AutoTrackConfig | None = None) -> tuple[KittiRows, float]:
    """Track one sequence; returns the results as KITTI rows and the tracking time in seconds."""
    tracker = AutoTrack(config, n_attributes=5)
    out_frame, out_id, out_cls, out_box, out_img, out_alpha, out_score = [], [], [], [], [], [], []
    t0 = time.perf_counter()
    for f, msg in enumerate(seq.messages):
        tracker.update(msg)
        tr = tracker.tracks(msg.stamp)
        if len(tr):
            out_frame.append(np.full(len(tr), f))
            out_id.append(tr.ids)
            out_cls.append(tr.class_id)
            out_box.append(tr.table[:, :7])
            out_img.append(tr.attributes[:, :4])
            out_alpha.append(tr.attributes[:, 4])
            out_score.append(tr.score)
    elapsed = time.perf_counter() - t0
    if out_frame:
        cls = np.concatenate(out_cls)
        rows = KittiRows(
            frame=np.concatenate(out_frame).astype(np.int64),
            track_id=np.concatenate(out_id),
            obj_type=np.array([CLASS_TO_KITTI.get(int(c), "Misc") for c in cls], dtype=object),
            truncation=np.zeros(cls.size),
            occlusion=np.zeros(cls.size, np.int64),
            alpha_rad=np.concatenate(out_alpha),
            image_box=np.concatenate(out_img),
            camera_box=kitti_camera_from_boxes(np.concatenate(out_box)),
            score=np.concatenate(out_score),
        )
    else:
        rows = KittiRows.empty()
    return rows, elapsed


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiRun:
    """Results of tracking and scoring several sequences."""

    per_class: dict[str, ClassResult]
    results: dict[str, KittiRows]
    frames: int
    tracking_s: float

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.tracking_s if self.tracking_s > 0 else float("inf")


def load_labels(labels_dir: Path, sequences: list[str]) -> dict[str, KittiRows]:
    """Labels of each sequence (raises ConfigError naming a missing file)."""
    return {s: read_labels(labels_dir / f"{s}.txt") for s in sequences}


def run_kitti(
    detections_dir: Path,
    labels_dir: Path,
    sequences: list[str],
    config: AutoTrackConfig | None = None,
) -> KittiRun:
    """Track ``sequences`` and score every class."""
    labels = load_labels(labels_dir, sequences)
    results: dict[str, KittiRows] = {}
    frames = 0
    tracking_s = 0.0
    n_frames: dict[str, int] = {}
    for s in sequences:
        nf = int(labels[s].frame.max()) + 1 if len(labels[s]) else 0
        seq = load_sequence(detections_dir, s, nf)
        rows, el = track_sequence(seq, config)
        results[s] = rows
        frames += seq.n_frames
        tracking_s += el
        n_frames[s] = nf
    per_class = {c: evaluate_class(labels, results, c, n_frames=n_frames) for c in CLASSES}
    return KittiRun(per_class=per_class, results=results, frames=frames, tracking_s=tracking_s)
