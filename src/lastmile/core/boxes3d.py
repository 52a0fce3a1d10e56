"""3D box detections (LiDAR, or LiDAR+radar fusion) and 3D box tracks: the 3D tracker's messages."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lastmile.core.arrays import frozen_array
from lastmile.core.box3d import BOX3D_COLUMNS
from lastmile.core.errors import MessageError
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp

_N_CLASSES = len(ObjectClass)


def _attributes(values: np.ndarray, what: str) -> np.ndarray:
    # Not frozen_array: an (N, 0) array has size 0 and would be reshaped to (0, 0) there.
    arr = np.array(values, dtype=np.float64, copy=True)
    if arr.ndim != 2:
        raise MessageError(f"{what}: expected shape (N, A), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise MessageError(f"{what}: expected finite values, got NaN or inf")
    arr.setflags(write=False)
    return arr


def _rows(arr: np.ndarray, n: int, what: str) -> None:
    if arr.shape[0] != n:
        raise MessageError(f"{what}: expected {n} rows (one per box), got {arr.shape[0]}")


@dataclass(frozen=True, slots=True, kw_only=True)
class DetectedBoxes:
    """3D boxes detected at one capture ``stamp`` by one source.

    Attributes:
        frame: frame of the boxes ("map" for the stack; any fixed frame, e.g. "kitti_camera_ground").
        source: producer ("lidar_front", "fusion", "pointrcnn", ...).
        boxes: (N, 7) float64, :data:`lastmile.core.box3d.BOX3D_COLUMNS` (z up, centre height).
        class_id: (N,) int64 :class:`ObjectClass` values.
        score: (N,) float64 detector confidence (any monotonic scale).
        velocity_mps: (N, 2) float64 over-ground velocity (vx, vy) measured by a radar, where
            ``has_velocity`` is true (else ignored, 0).
        has_velocity: (N,) bool, the box carries a radar Doppler velocity.
        attributes: (N, A) float64 opaque columns carried to the track the box last updates
            (e.g. KITTI's image box); A may be 0.
    """

    stamp: Stamp
    frame: str
    source: str
    boxes: np.ndarray
    class_id: np.ndarray
    score: np.ndarray
    velocity_mps: np.ndarray
    has_velocity: np.ndarray
    attributes: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "boxes", frozen_array(self.boxes, np.float64, len(BOX3D_COLUMNS), "DetectedBoxes.boxes")
        )
        object.__setattr__(
            self, "class_id", frozen_array(self.class_id, np.int64, None, "DetectedBoxes.class_id")
        )
        object.__setattr__(self, "score", frozen_array(self.score, np.float64, None, "DetectedBoxes.score"))
        object.__setattr__(
            self, "velocity_mps", frozen_array(self.velocity_mps, np.float64, 2, "DetectedBoxes.velocity_mps")
        )
        object.__setattr__(
            self,
            "has_velocity",
            frozen_array(self.has_velocity, np.bool_, None, "DetectedBoxes.has_velocity"),
        )
        object.__setattr__(self, "attributes", _attributes(self.attributes, "DetectedBoxes.attributes"))
        self.validate()

    def validate(self) -> None:
        """Check shapes, classes, extents and the stamp.

        Raises:
            MessageError: naming the field, what was expected and what arrived.
        """
        n = self.boxes.shape[0]
        for name in ("class_id", "score", "velocity_mps", "has_velocity", "attributes"):
            _rows(getattr(self, name), n, f"DetectedBoxes.{name}")
        if self.stamp < 0:
            raise MessageError(f"DetectedBoxes.stamp: expected >= 0 microseconds, got {self.stamp}")
        if np.any(self.boxes[:, 3:6] < 0.0):
            raise MessageError("DetectedBoxes.boxes: expected non-negative extents, got a negative one")
        if n and (self.class_id.min() < 0 or self.class_id.max() >= _N_CLASSES):
            raise MessageError(
                f"DetectedBoxes.class_id: expected ObjectClass values 0..{_N_CLASSES - 1}, "
                f"got {sorted(set(self.class_id.tolist()))}"
            )

    def __len__(self) -> int:
        return int(self.boxes.shape[0])


TRACK_BOX_COLUMNS = (*BOX3D_COLUMNS, "vx_mps", "vy_mps", "yaw_rate_radps", "pos_std_m", "age_s")
"""Columns of :attr:`TrackedBoxes.table`: the box, its velocity and turn rate, uncertainty, age."""


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackedBoxes:
    """Published (full) 3D tracks at ``stamp``.

    Attributes:
        ids: (N,) int64 track ids, stable over a track's life.
        table: (N, 12) float64, :data:`TRACK_BOX_COLUMNS`.
        class_id: (N,) int64 most probable :class:`ObjectClass` (class HMM).
        class_prob: (N, len(ObjectClass)) float64 class posterior, rows sum to 1.
        score: (N,) float64 confidence (score of the last detection, lowered while coasting).
        updated: (N,) bool, a detection updated the track at ``stamp``.
        attributes: (N, A) float64 the attributes of each track's last detection.
    """

    stamp: Stamp
    ids: np.ndarray
    table: np.ndarray
    class_id: np.ndarray
    class_prob: np.ndarray
    score: np.ndarray
    updated: np.ndarray
    attributes: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "ids", frozen_array(self.ids, np.int64, None, "TrackedBoxes.ids"))
        object.__setattr__(
            self, "table", frozen_array(self.table, np.float64, len(TRACK_BOX_COLUMNS), "TrackedBoxes.table")
        )
        object.__setattr__(
            self, "class_id", frozen_array(self.class_id, np.int64, None, "TrackedBoxes.class_id")
        )
        object.__setattr__(
            self,
            "class_prob",
            frozen_array(self.class_prob, np.float64, _N_CLASSES, "TrackedBoxes.class_prob"),
        )
        object.__setattr__(self, "score", frozen_array(self.score, np.float64, None, "TrackedBoxes.score"))
        object.__setattr__(
            self, "updated", frozen_array(self.updated, np.bool_, None, "TrackedBoxes.updated")
        )
        object.__setattr__(self, "attributes", _attributes(self.attributes, "TrackedBoxes.attributes"))
        self.validate()

    def validate(self) -> None:
        """Check that every field has one row per track.

        Raises:
            MessageError: naming the field, what was expected and what arrived.
        """
        n = self.ids.shape[0]
        for name in ("table", "class_id", "class_prob", "score", "updated", "attributes"):
            arr = getattr(self, name)
            if arr.shape[0] != n:
                raise MessageError(f"TrackedBoxes.{name}: expected {n} rows (one per id), got {arr.shape[0]}")

    def __len__(self) -> int:
        return int(self.ids.shape[0])
