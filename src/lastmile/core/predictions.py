"""Predicted future positions of tracked objects: what tracking's prediction hands to decision/planning."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lastmile.core.arrays import frozen_array
from lastmile.core.errors import MessageError
from lastmile.core.stamp import Stamp

PREDICTION_MODES = ("constant_velocity", "lane_following", "to_crosswalk")
"""Values of :attr:`PredictedPaths.mode` index this tuple."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PredictedPaths:
    """One predicted path per track, sampled at ``times_s`` after ``stamp``.

    Attributes:
        ids: (N,) int64 track ids.
        times_s: (T,) float64 seconds after ``stamp``, increasing, first > 0.
        xy_m: (N, T, 2) float64 predicted centre positions (map frame).
        std_m: (N, T) float64 one-sigma position uncertainty (per axis) at each time.
        mode: (N,) int64 index into :data:`PREDICTION_MODES`.
    """

    stamp: Stamp
    ids: np.ndarray
    times_s: np.ndarray
    xy_m: np.ndarray
    std_m: np.ndarray
    mode: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "ids", frozen_array(self.ids, np.int64, None, "PredictedPaths.ids"))
        object.__setattr__(
            self, "times_s", frozen_array(self.times_s, np.float64, None, "PredictedPaths.times_s")
        )
        n, t = self.ids.shape[0], self.times_s.shape[0]
        xy = (
            np.array(self.xy_m, dtype=np.float64).reshape(n, t, 2)
            if np.size(self.xy_m) == n * t * 2
            else None
        )
        if xy is None:
            raise MessageError(
                f"PredictedPaths.xy_m: expected shape ({n}, {t}, 2), got {np.shape(self.xy_m)}"
            )
        if not np.all(np.isfinite(xy)):
            raise MessageError("PredictedPaths.xy_m: expected finite values, got NaN or inf")
        xy.setflags(write=False)
        object.__setattr__(self, "xy_m", xy)
        std = frozen_array(np.reshape(self.std_m, (n, t)), np.float64, t, "PredictedPaths.std_m")
        object.__setattr__(self, "std_m", std)
        object.__setattr__(self, "mode", frozen_array(self.mode, np.int64, None, "PredictedPaths.mode"))
        self.validate()

    def validate(self) -> None:
        """Check times, modes and uncertainties.

        Raises:
            MessageError: naming the field, what was expected and what arrived.
        """
        if self.times_s.size and (self.times_s[0] <= 0.0 or np.any(np.diff(self.times_s) <= 0.0)):
            raise MessageError(f"PredictedPaths.times_s: expected increasing times > 0, got {self.times_s}")
        if self.mode.shape[0] != self.ids.shape[0]:
            raise MessageError(
                f"PredictedPaths.mode: expected {self.ids.shape[0]} rows, got {self.mode.shape[0]}"
            )
        if self.mode.size and (self.mode.min() < 0 or self.mode.max() >= len(PREDICTION_MODES)):
            raise MessageError(
                f"PredictedPaths.mode: expected 0..{len(PREDICTION_MODES) - 1}, got {self.mode}"
            )
        if np.any(self.std_m < 0.0):
            raise MessageError("PredictedPaths.std_m: expected >= 0, got a negative value")

    def __len__(self) -> int:
        return int(self.ids.shape[0])
