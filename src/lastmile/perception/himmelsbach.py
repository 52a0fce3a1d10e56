"""aUToronto's ground removal: Himmelsbach et al. (2010) line fitting in polar segments.

The plane around the vehicle is cut into angular segments and each segment into range bins. Each
bin's prototype is its lowest point, as (range, z). Walking outward, prototypes are added to the
current line while the least-squares fit stays flat enough (|m| <= max_slope), stays low when it is
nearly flat (|m| <= small_slope requires |b| <= max_intercept_m, which rejects car roofs and
walls' tops) and fits well (RMSE <= max_rmse_m); otherwise the line is closed and a new one starts.
A closed line is ground only if it also starts within ``max_step_m`` of the previous ground line
of its segment (T_d_prev), so a roof seen alone in its segment is not ground.
A point is ground when it lies no more than ``ground_distance_m`` above its bin's line. Each segment
is walked on its own in a compiled kernel (:mod:`lastmile.perception.himmelsbach_kernel`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError
from lastmile.perception.himmelsbach_kernel import (
    fill_forward,
    label_points,
    lowest_per_cell,
    point_cells,
    walk_lines,
)
from lastmile.perception.road_region import RoadMask


@dataclass(frozen=True, slots=True, kw_only=True)
class HimmelsbachConfig:
    """Parameters (Himmelsbach et al.'s T_m, T_m_small, T_b, T_RMSE, T_d_ground), metres and rise/run.

    Attributes:
        n_segments: angular segments over 360 degrees.
        bin_m: radial bin length.
        max_range_m: points beyond are left to the outermost bin's line.
        max_slope: T_m, steepest line accepted.
        small_slope: T_m_small, lines flatter than this must start low.
        max_intercept_m: T_b, height at range 0 allowed for nearly flat lines.
        max_rmse_m: T_RMSE, worst fit accepted.
        ground_distance_m: T_d_ground, tolerance above the line.
        max_step_m: T_d_prev, largest height jump between a line's start and the previous ground
            line, plus max_slope per metre of unseen ground between them (lines starting higher
            are object surfaces: roofs, wall tops).
        max_gap_m: a prototype farther than this from the line's last one starts a new line.
    """

    n_segments: int = 180
    bin_m: float = 0.5
    max_range_m: float = 100.0
    max_slope: float = 0.15
    small_slope: float = 0.03
    max_intercept_m: float = 0.3
    max_rmse_m: float = 0.08
    ground_distance_m: float = 0.2
    max_step_m: float = 0.3
    max_gap_m: float = 4.0

    def __post_init__(self) -> None:
        if self.n_segments < 4:
            raise ConfigError(f"HimmelsbachConfig.n_segments: expected >= 4, got {self.n_segments}")
        for name in (
            "bin_m",
            "max_range_m",
            "max_slope",
            "max_intercept_m",
            "max_rmse_m",
            "ground_distance_m",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"HimmelsbachConfig.{name}: expected a positive number, got {v}")
        if not (0 <= self.small_slope <= self.max_slope):
            raise ConfigError(
                f"HimmelsbachConfig.small_slope: expected in [0, max_slope={self.max_slope}], "
                f"got {self.small_slope}"
            )
        if self.max_range_m < 2 * self.bin_m:
            raise ConfigError(f"HimmelsbachConfig.max_range_m: expected >= 2 bins, got {self.max_range_m}")


class HimmelsbachGroundSegmenter:
    """Line-fit ground segmentation in polar segments (the road mask is not used)."""

    def __init__(self, config: HimmelsbachConfig | None = None) -> None:
        self.config = config or HimmelsbachConfig()

    def segment(self, xyz_m: npt.ArrayLike, road_mask: RoadMask | None = None) -> npt.NDArray[np.bool_]:
        cfg = self.config
        p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
        n = len(p)
        if n == 0:
            return np.zeros(0, dtype=bool)
        S = cfg.n_segments
        B = math.ceil(cfg.max_range_m / cfg.bin_m)
        r = np.hypot(p[:, 0], p[:, 1])
        z = np.ascontiguousarray(p[:, 2])
        seg, b = point_cells(r, np.arctan2(p[:, 1], p[:, 0]), S, B, cfg.bin_m)
        cell = seg * B + b
        # Prototype of each (segment, bin): its lowest point.
        proto_z = lowest_per_cell(cell, z, S * B)
        proto_r = (np.arange(B) + 0.5) * cfg.bin_m
        has = np.isfinite(proto_z).reshape(S, B)
        pz = np.where(has, proto_z.reshape(S, B), 0.0)
        # Each segment walked outward (compiled, :mod:`himmelsbach_kernel`): a prototype joins the
        # current line while the fit stays flat, low when nearly flat, tight and without a gap;
        # otherwise the line is closed, judged (slope, intercept, continuity with the segment's
        # last ground line across unseen ground) and a new one starts.
        line_m, line_b, valid, bin_line = walk_lines(
            has, pz, proto_r, cfg.max_slope, cfg.small_slope, cfg.max_intercept_m, cfg.max_rmse_m,
            cfg.max_step_m, cfg.max_gap_m,
        )  # fmt: skip

        # Bins without a prototype use the nearest line before them in range (after them at the start).
        filled = fill_forward(bin_line)  # compiled: the array form is _fill_forward
        return label_points(seg, b, r, z, filled, line_m, line_b, valid, cfg.ground_distance_m)


def _fill_forward(ids: np.ndarray) -> np.ndarray:
    """Replace -1 entries by the last non-negative entry to their left (or the first to their right).

    The array form of ``himmelsbach_kernel.fill_forward`` (which the segmenter calls), kept as the
    reference the kernel is tested against."""
    S, B = ids.shape
    pos = np.where(ids >= 0, np.arange(B)[None, :], -1)
    last = np.maximum.accumulate(pos, axis=1)
    out = np.where(last >= 0, np.take_along_axis(ids, np.maximum(last, 0), axis=1), -1)
    first = np.where((ids >= 0).any(axis=1), np.argmax(ids >= 0, axis=1), 0)
    lead = out < 0
    return np.where(lead, ids[np.arange(S), first][:, None], out)
