"""Detected and tracked objects, struct-of-arrays."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lastmile.core.arrays import frozen_array
from lastmile.core.errors import MessageError
from lastmile.core.stamp import Stamp

DETECTION_COLUMNS = ("x_m", "y_m", "vx_mps", "vy_mps", "length_m", "width_m", "yaw_rad", "class_id", "score")
"""Columns of :attr:`DetectedObjects.table`; ``class_id`` holds an :class:`ObjectClass` value."""

TRACK_COLUMNS = (
    "x_m",
    "y_m",
    "vx_mps",
    "vy_mps",
    "length_m",
    "width_m",
    "yaw_rad",
    "class_id",
    "pos_std_m",
    "age_s",
)
"""Columns of :attr:`TrackedObjects.table`."""


def column(name: str, columns: tuple[str, ...]) -> int:
    """Index of a named column (raises with the known names if absent)."""
    try:
        return columns.index(name)
    except ValueError:
        raise MessageError(f"column: expected one of {columns}, got {name!r}") from None


@dataclass(frozen=True, slots=True, kw_only=True)
class DetectedObjects:
    """One sensor's (or one fusion step's) detections at ``stamp``.

    Attributes:
        frame: the frame positions are in ("map" or "base"); velocities are over ground.
        source: which pipeline produced them ("radar_front", "fusion", "oracle", ...).
        table: (N, 9) float64, columns :data:`DETECTION_COLUMNS`.
    """

    stamp: Stamp
    frame: str
    source: str
    table: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "table",
            frozen_array(self.table, np.float64, len(DETECTION_COLUMNS), "DetectedObjects.table"),
        )
        if self.frame not in ("map", "base"):
            raise MessageError(f"DetectedObjects.frame: expected 'map' or 'base', got {self.frame!r}")

    def __len__(self) -> int:
        return int(self.table.shape[0])


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackedObjects:
    """Confirmed tracks in the map frame at ``stamp``.

    Attributes:
        ids: (N,) int64 track ids, stable over a track's life.
        table: (N, 10) float64, columns :data:`TRACK_COLUMNS`.
    """

    stamp: Stamp
    ids: np.ndarray
    table: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "ids", frozen_array(self.ids, np.int64, None, "TrackedObjects.ids"))
        object.__setattr__(
            self, "table", frozen_array(self.table, np.float64, len(TRACK_COLUMNS), "TrackedObjects.table")
        )
        if self.ids.shape[0] != self.table.shape[0]:
            raise MessageError(
                f"TrackedObjects: expected as many ids as rows, "
                f"got {self.ids.shape[0]} and {self.table.shape[0]}"
            )

    def __len__(self) -> int:
        return int(self.ids.shape[0])


def empty_tracks(stamp: Stamp) -> TrackedObjects:
    return TrackedObjects(stamp=stamp, ids=np.zeros(0, np.int64), table=np.zeros((0, len(TRACK_COLUMNS))))
