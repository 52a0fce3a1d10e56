"""A bird's-eye-view raster of a point cloud: the input tensor of a BEV LiDAR detector.

Layout: ``(1, C, H, W)`` float32; row ``r`` covers ``x_min_m + r * cell_m`` .. ``+ cell_m`` (forward),
column ``c`` covers ``y_min_m + c * cell_m`` .. ``+ cell_m`` (left), both in the base frame; points
outside the box ``[x_min, x_max) x [y_min, y_max) x [z_min, z_max)`` are left out. Channels, in the
order the configuration lists them (Complex-YOLO's height, intensity and density maps, and PIXOR's
occupancy):

- ``occupancy``: 1 where the cell holds a point, else 0;
- ``density``: ``min(1, ln(1 + n) / ln(64))`` for the cell's ``n`` points (Complex-YOLO);
- ``max_height``: the highest point's ``z - z_min_m`` in metres (0 in an empty cell);
- ``max_intensity``: the highest intensity in the cell / 255 (the pipeline's 0..255 scale).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from lastmile.core.errors import ConfigError, MessageError


class BevChannel(StrEnum):
    """A BEV raster channel (see the module docstring)."""

    OCCUPANCY = "occupancy"
    DENSITY = "density"
    MAX_HEIGHT = "max_height"
    MAX_INTENSITY = "max_intensity"


@dataclass(frozen=True, slots=True, kw_only=True)
class BevGrid:
    """The raster's extent, cell and channels; it must be the one the model was trained on.

    The defaults are PointPillars' KITTI grid (x 0..69.12 m, y -39.68..39.68 m, z -3..1 m from the
    LiDAR, 0.16 m cells), with z shifted to a base frame on the road under a sensor 1.73 m up.

    Attributes:
        x_min_m, x_max_m, y_min_m, y_max_m, z_min_m, z_max_m: the box of points rasterised (base frame).
        cell_m: the cell's side; the extents must be whole numbers of cells.
        channels: the channels, in tensor order.
    """

    x_min_m: float = 0.0
    x_max_m: float = 69.12
    y_min_m: float = -39.68
    y_max_m: float = 39.68
    z_min_m: float = -1.27
    z_max_m: float = 2.73
    cell_m: float = 0.16
    channels: tuple[BevChannel, ...] = (BevChannel.MAX_HEIGHT, BevChannel.MAX_INTENSITY, BevChannel.DENSITY)

    def __post_init__(self) -> None:
        values = (self.x_min_m, self.x_max_m, self.y_min_m, self.y_max_m, self.z_min_m, self.z_max_m)
        if not all(math.isfinite(v) for v in values) or not (
            self.x_min_m < self.x_max_m and self.y_min_m < self.y_max_m and self.z_min_m < self.z_max_m
        ):
            raise ConfigError(f"BevGrid: expected finite extents with min < max, got {values}")
        if not (math.isfinite(self.cell_m) and 0.01 <= self.cell_m <= 5.0):
            raise ConfigError(f"BevGrid.cell_m: expected 0.01..5 m, got {self.cell_m}")
        for name, span in (("x", self.x_max_m - self.x_min_m), ("y", self.y_max_m - self.y_min_m)):
            cells = span / self.cell_m
            if abs(cells - round(cells)) > 1e-6 * max(1.0, cells):
                raise ConfigError(
                    f"BevGrid: expected the {name} extent ({span} m) to be a whole number of "
                    f"{self.cell_m} m cells, got {cells:.4f} cells"
                )
        if not self.channels or len(set(self.channels)) != len(self.channels):
            raise ConfigError(f"BevGrid.channels: expected distinct channels, got {list(self.channels)}")
        if self.rows * self.cols > 4_000_000:
            raise ConfigError(f"BevGrid: expected at most 4M cells, got {self.rows} x {self.cols}")

    @property
    def rows(self) -> int:
        """H: cells along x."""
        return round((self.x_max_m - self.x_min_m) / self.cell_m)

    @property
    def cols(self) -> int:
        """W: cells along y."""
        return round((self.y_max_m - self.y_min_m) / self.cell_m)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """The tensor's shape (1, C, H, W)."""
        return (1, len(self.channels), self.rows, self.cols)


def bev_tensor(xyz_m: np.ndarray, intensity: np.ndarray, grid: BevGrid) -> np.ndarray:
    """Rasterise points into the grid's ``(1, C, H, W)`` float32 tensor.

    Args:
        xyz_m: (N, 3) base-frame points.
        intensity: (N,) intensities on the 0..255 scale.
        grid: extent, cell and channels.

    Raises:
        MessageError: wrong shapes or non-finite values.
    """
    xyz = np.asarray(xyz_m, dtype=np.float64)
    inten = np.asarray(intensity, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or inten.shape != (len(xyz),):
        raise MessageError(
            f"bev_tensor: expected (N, 3) points and (N,) intensities, got {xyz.shape} and {inten.shape}"
        )
    if not (np.isfinite(xyz).all() and np.isfinite(inten).all()):
        raise MessageError("bev_tensor: expected finite points and intensities, got NaN or inf")
    H, W = grid.rows, grid.cols
    r = np.floor((xyz[:, 0] - grid.x_min_m) / grid.cell_m).astype(np.int64)
    c = np.floor((xyz[:, 1] - grid.y_min_m) / grid.cell_m).astype(np.int64)
    inside = (
        (r >= 0) & (r < H) & (c >= 0) & (c < W) & (xyz[:, 2] >= grid.z_min_m) & (xyz[:, 2] < grid.z_max_m)
    )
    cell = r[inside] * W + c[inside]
    z = xyz[inside, 2] - grid.z_min_m
    i = inten[inside]
    count = np.bincount(cell, minlength=H * W)
    out = np.zeros((len(grid.channels), H * W), dtype=np.float32)
    for k, channel in enumerate(grid.channels):
        if channel is BevChannel.OCCUPANCY:
            out[k] = count > 0
        elif channel is BevChannel.DENSITY:
            out[k] = np.minimum(1.0, np.log1p(count) / math.log(64.0))
        elif channel is BevChannel.MAX_HEIGHT:
            top = np.zeros(H * W)
            np.maximum.at(top, cell, z)
            out[k] = top
        else:
            top = np.zeros(H * W)
            np.maximum.at(top, cell, i / 255.0)
            out[k] = top
    return out.reshape(grid.shape)
