"""Pedestrians carved out of the larger clusters they were merged into (a wall, a hedge, a parked car).

Euclidean clustering at 0.5 m joins a pedestrian standing within half a metre of anything else, and
its feet join it to whatever ground clutter lies between (a kerb top, leaves, the ground removal's
leftovers). For every cluster wider than ``min_extent_m`` (larger than any pedestrian), the points
standing at least ``body_min_height_m`` above the ground (the lowest ground return in their
``floor_cell_m`` cell or its neighbours; points with none there take no part) are clustered
again in the ground plane at ``split_eps_m``; a component with a pedestrian's shape (footprint at
most ``max_footprint_m`` across, its lowest point at most ``max_foot_height_m`` above the ground,
its top ``min_height_m`` to ``max_height_m`` above it, at least ``min_points`` returns) becomes a
cluster of its own,
together with the low points under it (within ``split_eps_m`` of its footprint). The rest of the
cluster keeps its label. Nothing is split where no pedestrian-shaped part comes out, so cars and
rows of a sparse LiDAR stay whole.

The shape bounds are those of standing and walking adults and children: KITTI's pedestrian boxes
are 0.3-1.2 m long and wide and 1.0-2.0 m tall (its labels' range); ``split_eps_m`` = 0.25 m, half
the clustering link, is wider than the HDL-64E's or VLP-32C's ring spacing out to ~30 m (0.4 and
0.33 deg), so a body is not cut into rows there. A pedestrian-shaped part may be a post, a bollard
or a stretch of hedge as well: the stage is off by default (see the README for what it did on the
KITTI frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError
from lastmile.perception.clustering import euclidean_cluster_labels

IntArray = npt.NDArray[np.int64]
_KEY_STRIDE = 1_000_003


@dataclass(frozen=True, slots=True, kw_only=True)
class ClusterSplitConfig:
    """Attributes (metres unless stated):
    enabled: run the split (the pipeline's stage between clustering and cluster geometry).
    min_extent_m: clusters whose footprint's larger side is at most this are left alone.
    body_min_height_m: points lower than this above their cell's floor do not join the re-clustering
        (they bridge a pedestrian's feet to the clutter around them).
    floor_cell_m: cell of the local floor (the cluster's lowest point in the cell).
    split_eps_m: link length of the re-clustering.
    max_footprint_m, max_foot_height_m, min_height_m, max_height_m: a pedestrian's shape (the
        footprint's larger side; its lowest and highest point above the ground). The lowest
        return on a person is not at the ground: the ground removal takes the lowest 0.1-0.2 m,
        and a VLP-32C's lower beams are ~1 deg apart (0.2-0.35 m between rows at 10-20 m), so
        the feet may first show 0.5 m up; 0.8 m still tells legs from a wall's top or a canopy.
    min_points: fewest returns of a pedestrian-shaped component.
    """

    enabled: bool = False
    min_extent_m: float = 2.0
    body_min_height_m: float = 0.3
    floor_cell_m: float = 1.0
    split_eps_m: float = 0.25
    max_footprint_m: float = 1.2
    max_foot_height_m: float = 0.8
    min_height_m: float = 1.0
    max_height_m: float = 2.2
    min_points: int = 10

    def __post_init__(self) -> None:
        for name in (
            "min_extent_m",
            "body_min_height_m",
            "floor_cell_m",
            "split_eps_m",
            "max_footprint_m",
            "max_foot_height_m",
            "min_height_m",
            "max_height_m",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"ClusterSplitConfig.{name}: expected a positive number, got {v}")
        if self.max_height_m <= self.min_height_m or self.min_points < 3:
            raise ConfigError(
                "ClusterSplitConfig: expected max_height_m > min_height_m and min_points >= 3, got "
                f"{self.max_height_m} <= {self.min_height_m} or {self.min_points}"
            )


def split_pedestrians(
    xyz_m: npt.ArrayLike, labels: npt.ArrayLike, ground: npt.ArrayLike, config: ClusterSplitConfig
) -> IntArray:
    """Labels with pedestrian-shaped parts of large clusters given labels of their own.

    Args:
        xyz_m: (N, 3) base-frame points.
        labels: (N,) int64 cluster labels, -1 for unclustered points.
        ground: (N,) bool ground points (the floor under the clusters).
        config: parameters.

    Returns:
        (N,) int64 labels: unchanged except for the carved-out parts, numbered after the largest.
    """
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    out = np.array(labels, dtype=np.int64, copy=True)
    has = np.flatnonzero(out >= 0)
    if len(has) == 0:
        return out
    lab = out[has]
    n = int(lab.max()) + 1
    by_label = has[np.argsort(lab, kind="stable")]
    starts = np.searchsorted(out[by_label], np.arange(n + 1))
    present = np.flatnonzero(starts[1:] > starts[:-1])
    xy = p[by_label, :2]
    # Per-label extents by segment reductions over the label-sorted points (ufunc.at is slow).
    lo = np.minimum.reduceat(xy, starts[present], axis=0)
    hi = np.maximum.reduceat(xy, starts[present], axis=0)
    large = present[(hi - lo).max(axis=1) > config.min_extent_m]
    if len(large) == 0:
        return out
    floor = _GroundFloor(p[np.asarray(ground, dtype=bool)], config.floor_cell_m)
    next_label = n
    for k in large.tolist():
        members = by_label[starts[k] : starts[k + 1]]
        for part in _pedestrian_parts(p[members], floor, config):
            out[members[part]] = next_label
            next_label += 1
    return out


class _GroundFloor:
    """The lowest ground return per cell and its eight neighbours, looked up by point (NaN where
    none of the nine holds one: the floor there is unknown)."""

    def __init__(self, ground_xyz: np.ndarray, cell_m: float) -> None:
        self.cell_m = cell_m
        keys = self._keys(np.floor(ground_xyz[:, :2] / cell_m).astype(np.int64))
        order = np.argsort(keys, kind="stable")
        keys = keys[order]
        first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if len(keys) else np.zeros(0, np.int64)
        self.keys = keys[first]
        self.z = np.minimum.reduceat(ground_xyz[order, 2], first) if len(first) else np.zeros(0)

    @staticmethod
    def _keys(cells: np.ndarray) -> np.ndarray:
        return cells[:, 0] * _KEY_STRIDE + cells[:, 1]

    def at(self, xy: np.ndarray) -> np.ndarray:
        if len(self.keys) == 0:
            return np.full(len(xy), np.nan)
        # Looked up once per distinct cell of the points, then spread back to the points; the
        # neighbours' keys are the cell's key shifted (cells stay far inside +-_KEY_STRIDE / 2).
        keys, inverse = np.unique(
            self._keys(np.floor(xy / self.cell_m).astype(np.int64)), return_inverse=True
        )
        out = np.full(len(keys), np.inf)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                k = keys + (dx * _KEY_STRIDE + dy)
                i = np.minimum(np.searchsorted(self.keys, k), len(self.keys) - 1)
                out = np.where(self.keys[i] == k, np.minimum(out, self.z[i]), out)
        return np.where(np.isfinite(out), out, np.nan)[inverse.reshape(-1)]


def _pedestrian_parts(q: np.ndarray, floor_map: _GroundFloor, config: ClusterSplitConfig) -> list[np.ndarray]:
    """Boolean masks over one cluster's points (M, 3), one per pedestrian-shaped part (low points
    under it included); empty when none, or when the whole cluster would go."""
    c = config
    floor = floor_map.at(q[:, :2])
    # Points over an unknown floor (no ground return within a cell) are neither body nor feet.
    height = q[:, 2] - floor
    body = np.flatnonzero(height >= c.body_min_height_m)
    if len(body) < c.min_points:
        return []
    # In the ground plane: a body is a column of rows that may lie farther apart vertically than
    # the link length (a VLP-32C's lower beams are ~1 deg apart, 0.2 m at 10 m).
    flat = np.column_stack([q[body, 0], q[body, 1], np.zeros(len(body))])
    sub = euclidean_cluster_labels(flat, c.split_eps_m)
    parts: list[np.ndarray] = []
    taken = np.zeros(len(q), dtype=bool)
    low = np.flatnonzero(height < c.body_min_height_m)  # NaN compares False: unknown floors out
    # Components as segments of the component-sorted body points; shape tests by segment
    # reductions, so a wall broken into hundreds of pieces costs one pass, not one per piece.
    order = np.argsort(sub, kind="stable")
    seg = np.flatnonzero(np.r_[True, sub[order][1:] != sub[order][:-1]])
    size = np.diff(np.r_[seg, len(order)])
    bxy = q[body[order], :2]
    span = (np.maximum.reduceat(bxy, seg, axis=0) - np.minimum.reduceat(bxy, seg, axis=0)).max(axis=1)
    top = np.maximum.reduceat(height[body[order]], seg)
    shaped = (size >= c.min_points) & (span <= c.max_footprint_m)
    shaped &= (top >= c.min_height_m) & (top <= c.max_height_m)
    for j in np.flatnonzero(shaped).tolist():
        idx = body[order[seg[j] : seg[j] + size[j]]]
        xy = q[idx, :2]
        # The feet: low points within the link length of the part's footprint box.
        lo_xy, hi_xy = xy.min(axis=0) - c.split_eps_m, xy.max(axis=0) + c.split_eps_m
        feet = low[np.all((q[low, :2] >= lo_xy) & (q[low, :2] <= hi_xy), axis=1)]
        foot = float(min(height[idx].min(), height[feet].min(initial=np.inf)))
        if foot > c.max_foot_height_m:
            continue
        mask = np.zeros(len(q), dtype=bool)
        mask[idx] = True
        mask[feet] = True
        mask &= ~taken
        taken |= mask
        parts.append(mask)
    if taken.all():
        return []  # the cluster was nothing but pedestrians' parts: it needs no split
    return parts
