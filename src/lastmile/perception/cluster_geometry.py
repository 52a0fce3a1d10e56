"""Per-cluster geometry and aUToronto's intensity-based classes, vectorised over all clusters.

For every cluster that passes the range-dependent size filter: height span, mean intensity, a 2-D
convex hull and the minimum-area oriented rectangle. The hull is the polygon of the cluster's
support points in ``hull_directions`` evenly spaced directions: every vertex is a true hull vertex,
and between two adjacent support vertices the true hull lies within half the chord times
``tan(pi / hull_directions)`` of it. The rectangle's orientation starts as the optimum for that
polygon (rotating calipers: the optimal rectangle has a side on a hull edge) and is then refined
within one angular spacing on the hull candidates (which hold every true hull vertex); its extents
come from all the cluster's points, so the box always contains the whole cluster. One pass of array operations
serves every cluster, so hundreds of clusters cost milliseconds rather than a Qhull call each.

aUToronto (6.2.2) found that splitting the cloud by intensity before clustering breaks reflective
objects apart, so intensity is used only after clustering: a cluster shaped like a barrel, a
barricade or a sign gets that kind, with high confidence when its mean intensity exceeds
``reflective_intensity``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError, MessageError
from lastmile.perception.cluster_geometry_kernel import (
    box_extents,
    calipers_pick,
    cloud_cluster_sums,
    gather_by_cluster,
    hull_support,
    refine_pick,
)

CLUSTER_COLUMNS = (
    "x_m",
    "y_m",
    "z_min_m",
    "z_max_m",
    "length_m",
    "width_m",
    "yaw_rad",
    "n_points",
    "mean_intensity",
    "range_m",
    "kind",
    "confidence",
)
"""Columns of :attr:`ClusterSet.table`; x, y are the oriented box's centre (base frame)."""


class ClusterKind(IntEnum):
    """Static road furniture aUToronto classifies from LiDAR; anything else is OTHER."""

    OTHER = 0
    BARREL = 1
    BARRICADE = 2
    SIGN = 3


@dataclass(frozen=True, slots=True, kw_only=True)
class ClusterGeometryConfig:
    """Attributes:
    min_points_at_1m: a cluster at range r needs ``min_points_at_1m / r**2`` points (the expected
        point count of a fixed-size object falls with the square of range) ...
    min_points_floor: ... but never fewer than this (2 keeps a goose at 30 m: ~5 returns) ...
    min_points_cap: ... nor more than this near the sensor.
    reflective_intensity: mean intensity (0..255 scale) above which a cluster is retro-reflective.
    max_height_m: clusters whose bottom is above this (overhanging branches) are dropped.
    hull_directions: support directions of the hull polygon (>= 8).
    """

    min_points_at_1m: float = 200.0
    min_points_floor: int = 2
    min_points_cap: int = 8
    reflective_intensity: float = 150.0
    max_height_m: float = 3.5
    hull_directions: int = 32

    def __post_init__(self) -> None:
        if not (self.min_points_at_1m >= 0 and 1 <= self.min_points_floor <= self.min_points_cap):
            raise ConfigError(
                "ClusterGeometryConfig: expected min_points_at_1m >= 0 and 1 <= floor <= cap, got "
                f"{self.min_points_at_1m}, {self.min_points_floor}, {self.min_points_cap}"
            )
        if self.hull_directions < 8:
            raise ConfigError(
                f"ClusterGeometryConfig.hull_directions: expected >= 8, got {self.hull_directions}"
            )
        if not (math.isfinite(self.reflective_intensity) and math.isfinite(self.max_height_m)):
            raise ConfigError("ClusterGeometryConfig: expected finite intensity and height limits")

    def min_points(self, range_m: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Minimum cluster size at the given ranges."""
        r = np.maximum(np.asarray(range_m, dtype=np.float64), 0.1)
        n = np.ceil(self.min_points_at_1m / (r * r))
        return np.clip(n, self.min_points_floor, self.min_points_cap).astype(np.int64)


@dataclass(frozen=True, slots=True, kw_only=True)
class ClusterSet:
    """Clusters kept after the size filter.

    Attributes:
        table: (K, 12) float64, columns :data:`CLUSTER_COLUMNS`.
        hull_xy: (K, D, 2) float64 hull vertices counter-clockwise, padded by repeating vertices.
        hull_new: (K, D) bool, False where a vertex repeats the previous one.
        labels: (K,) int64, the clustering label of each kept cluster.
    """

    table: np.ndarray
    hull_xy: np.ndarray
    hull_new: np.ndarray
    labels: np.ndarray

    def hull(self, i: int) -> np.ndarray:
        """(H, 2) distinct counter-clockwise hull vertices of cluster row ``i``."""
        v = self.hull_xy[i][self.hull_new[i]]
        return v if len(v) else self.hull_xy[i][:1]

    def __len__(self) -> int:
        return int(self.table.shape[0])

    def col(self, name: str) -> np.ndarray:
        return self.table[:, CLUSTER_COLUMNS.index(name)]


def classify_kind(length_m: float, width_m: float, z_min_m: float, z_max_m: float) -> ClusterKind:
    """Shape rule for road furniture (dimensions of traffic barrels, barricades and sign plates)."""
    height = z_max_m - z_min_m
    if z_max_m >= 1.5 and width_m <= 0.25 and length_m <= 1.2 and height >= 0.3:
        return ClusterKind.SIGN
    if 0.35 <= length_m <= 0.9 and 0.35 <= width_m <= 0.9 and 0.6 <= height <= 1.4 and z_min_m < 0.3:
        return ClusterKind.BARREL
    if 0.9 < length_m <= 2.8 and width_m <= 0.7 and 0.6 <= height <= 1.6 and z_min_m < 0.5:
        return ClusterKind.BARRICADE
    return ClusterKind.OTHER


def describe_clusters(
    xyz_m: npt.ArrayLike,
    intensity: npt.ArrayLike,
    labels: npt.ArrayLike,
    config: ClusterGeometryConfig | None = None,
    point_weight: npt.ArrayLike | None = None,
) -> ClusterSet:
    """Geometry and kind of every cluster that passes the range-dependent size filter.

    Args:
        xyz_m: (N, 3) base-frame points.
        intensity: (N,) intensities (0..255).
        labels: (N,) int cluster labels 0..C-1 (from :func:`clustering.euclidean_cluster_labels`).
        point_weight: (N,) how many of the densest unit's returns each point stands for
            (:func:`scan_density.return_weights`); the size filter compares the weighted count with
            ``min_points`` and the plain count with ``min_points_floor``. None: every point 1.
    """
    cfg = config or ClusterGeometryConfig()
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    inten = np.asarray(intensity, dtype=np.float64).reshape(-1)
    lab = np.asarray(labels, dtype=np.int64).reshape(-1)
    if not (len(p) == len(inten) == len(lab)):
        raise MessageError(
            f"describe_clusters: expected equal lengths, got {len(p)} points, {len(inten)} intensities, "
            f"{len(lab)} labels"
        )
    D = cfg.hull_directions
    if len(p) == 0:
        return _empty(D)
    if lab.min() < 0:
        raise MessageError(f"describe_clusters: expected labels >= 0, got {lab.min()}")
    n_cl = int(lab.max()) + 1
    # One sensor of weight 1: the weighted size is the count (the point weights are below).
    count, sum_x, sum_y, zmin, _ = cloud_cluster_sums(
        p, lab, np.zeros(len(lab), np.float32), np.ones(1), n_cl
    )
    size: np.ndarray = count
    if point_weight is not None:
        wt = np.asarray(point_weight, dtype=np.float64).reshape(-1)
        if wt.shape != (len(p),) or not (np.isfinite(wt).all() and (wt >= 1.0).all()):
            raise MessageError(
                f"describe_clusters.point_weight: expected ({len(p)},) finite >= 1, got {wt.shape}"
            )
        size = np.bincount(lab, weights=wt, minlength=n_cl)
    return _describe(p, inten, lab, count, sum_x, sum_y, zmin, size, cfg)


def describe_cloud_clusters(
    xyz_m: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    unit_weight: npt.ArrayLike | None = None,
    config: ClusterGeometryConfig | None = None,
) -> ClusterSet:
    """:func:`describe_clusters` of the labelled points of a whole merged cloud, read in place.

    The same clusters, to the bit, as ``describe_clusters(xyz_m[rows], points[rows, 3],
    labels[rows], config, unit_weight[sensor of rows])`` over the rows with a label; the sums, the
    weighted sizes and the grouping by cluster read the cloud directly (compiled passes), without
    gathering the labelled rows first.

    Args:
        xyz_m: (N, 3) float64 base-frame points of the cloud.
        points: (N, >= 6) float32 merged cloud (intensity in column 3, sensor index in column 5).
        labels: (N,) int64 cluster labels, negative for unclustered points.
        unit_weight: (S,) weight of one return of each LiDAR, by sensor index
            (:func:`scan_density.return_weights`, each >= 1); None: every point 1.
    """
    cfg = config or ClusterGeometryConfig()
    lab = np.asarray(labels, dtype=np.int64).reshape(-1)
    if not (len(xyz_m) == len(points) == len(lab)):
        raise MessageError(
            f"describe_cloud_clusters: expected equal lengths, got {len(xyz_m)} points, {len(points)} "
            f"cloud rows, {len(lab)} labels"
        )
    n_units = int(points[:, 5].max()) + 1 if len(points) else 1
    w = np.ones(n_units) if unit_weight is None else np.asarray(unit_weight, dtype=np.float64).reshape(-1)
    if not (np.isfinite(w).all() and (w >= 1.0).all()):
        raise MessageError(f"describe_cloud_clusters.unit_weight: expected finite >= 1, got {w}")
    if len(lab) == 0 or lab.max() < 0:
        return _empty(cfg.hull_directions)
    count, sum_x, sum_y, zmin, size = cloud_cluster_sums(xyz_m, lab, points[:, 5], w, int(lab.max()) + 1)
    return _describe(xyz_m, points[:, 3], lab, count, sum_x, sum_y, zmin, size, cfg)


def _describe(
    p: np.ndarray,
    inten: np.ndarray,
    lab: np.ndarray,
    count: np.ndarray,
    sum_x: np.ndarray,
    sum_y: np.ndarray,
    zmin: np.ndarray,
    size: np.ndarray,
    cfg: ClusterGeometryConfig,
) -> ClusterSet:
    """The size filter, then the geometry of the kept clusters, from the per-label sums."""
    D = cfg.hull_directions
    cx = sum_x / np.maximum(count, 1)
    cy = sum_y / np.maximum(count, 1)
    keep = (
        (count >= cfg.min_points_floor)
        & (size >= cfg.min_points(np.hypot(cx, cy)))
        & (zmin <= cfg.max_height_m)
    )
    kept = np.flatnonzero(keep)
    if len(kept) == 0:
        return _empty(D)
    # One pass gathers the kept points in cluster order (compiled counting sort).
    row_of_label = np.full(len(count), -1, dtype=np.int64)
    row_of_label[kept] = np.arange(len(kept))
    cnt = count[kept]
    x, y, ins, starts, z0, z1 = gather_by_cluster(p, inten, lab, row_of_label, cnt)
    # NumPy's segment sum (pairwise within long clusters), as before: the same mean to the bit.
    mean_i = np.add.reduceat(ins, starts) / cnt

    # Akl-Toussaint: points strictly inside the polygon of a few support points cannot be hull
    # vertices. A 4-gon then an 8-gon leave the 32-direction pass a few percent of the points.
    # The per-cluster loops run compiled (cluster_geometry_kernel); sines and cosines come from
    # NumPy so every value is the one the array version computed.
    hull_idx, is_cand = hull_support(x, y, starts, cnt, (_directions(4), _directions(8)), *_directions(D))
    hull_xy = np.stack([x[hull_idx], y[hull_idx]], axis=-1)  # (K, D, 2), counter-clockwise by construction
    hull_new = np.ones(hull_idx.shape, dtype=bool)
    hull_new[:, 1:] = hull_idx[:, 1:] != hull_idx[:, :-1]
    hull_new[:, 0] = hull_idx[:, 0] != hull_idx[:, -1]

    # Rotating calipers on the polygon: each edge direction (mod 90 deg) is a candidate axis.
    edges = np.roll(hull_xy, -1, axis=1) - hull_xy
    theta = np.arctan2(edges[..., 1], edges[..., 0]) % (math.pi / 2)  # (K, D)
    k = calipers_pick(hull_xy[..., 0], hull_xy[..., 1], np.cos(theta), np.sin(theta))
    r = np.arange(len(kept))
    best = _refine_orientation(theta[r, k], x, y, is_cand, starts, cnt, math.pi / D)
    ck, sk = np.cos(best), np.sin(best)
    # Extents along the chosen axes from every point, so the box holds the whole cluster even
    # where the direction-sampled hull missed a vertex.
    u0, u1, v0, v1 = box_extents(x, y, starts, cnt, ck, sk).T
    um, vm = (u0 + u1) / 2, (v0 + v1) / 2
    bx, by = um * ck - vm * sk, um * sk + vm * ck
    L, W, yaw = u1 - u0, v1 - v0, best
    swap = W > L
    L, W = np.where(swap, W, L), np.where(swap, L, W)
    yaw = np.where(swap, yaw + math.pi / 2, yaw)
    yaw = (yaw + math.pi / 2) % math.pi - math.pi / 2

    kind = _classify(L, W, z0, z1)
    conf = np.where(kind == ClusterKind.OTHER, 0.0, np.where(mean_i >= cfg.reflective_intensity, 0.9, 0.4))
    table = np.stack(
        [
            bx,
            by,
            z0,
            z1,
            L,
            W,
            yaw,
            cnt.astype(np.float64),
            mean_i,
            np.hypot(bx, by),
            kind.astype(np.float64),
            conf,
        ],
        axis=1,
    )
    return ClusterSet(table=table, hull_xy=hull_xy, hull_new=hull_new, labels=kept.astype(np.int64))


def _refine_orientation(
    theta: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    is_cand: np.ndarray,
    starts: np.ndarray,
    counts: np.ndarray,
    span_rad: float,
) -> np.ndarray:
    """(K,) rectangle orientations refined within +-``span_rad`` of ``theta`` on the hull candidates.

    The optimum has a side on a true hull edge, whose direction the direction-sampled polygon knows
    only to within its angular spacing, so the box can come out several per cent too large. The
    candidates (``is_cand``) hold every true hull vertex, so their extents along any axis are the
    cluster's: two passes of 17 angles each pin the orientation to 1/64 of the spacing.
    """
    best = theta
    r = np.arange(len(theta))
    for _ in range(2):
        ang = best[:, None] + np.linspace(-span_rad, span_rad, 17)[None, :]  # (K, 17)
        best = ang[r, refine_pick(x, y, is_cand, starts, counts, np.cos(ang), np.sin(ang))]
        span_rad /= 8.0
    return best


def _directions(D: int) -> tuple[np.ndarray, np.ndarray]:
    """Cosines and sines of D evenly spaced directions, counter-clockwise from +x."""
    ang = np.arange(D) * (2 * math.pi / D)
    return np.cos(ang), np.sin(ang)


def _empty(D: int) -> ClusterSet:
    return ClusterSet(
        table=np.zeros((0, len(CLUSTER_COLUMNS))),
        hull_xy=np.zeros((0, D, 2)),
        hull_new=np.zeros((0, D), dtype=bool),
        labels=np.zeros(0, np.int64),
    )


def _classify(L: np.ndarray, W: np.ndarray, z0: np.ndarray, z1: np.ndarray) -> np.ndarray:
    """Vectorised :func:`classify_kind`."""
    h = z1 - z0
    sign = (z1 >= 1.5) & (W <= 0.25) & (L <= 1.2) & (h >= 0.3)
    barrel = (L >= 0.35) & (L <= 0.9) & (W >= 0.35) & (W <= 0.9) & (h >= 0.6) & (h <= 1.4) & (z0 < 0.3)
    barricade = (L > 0.9) & (L <= 2.8) & (W <= 0.7) & (h >= 0.6) & (h <= 1.6) & (z0 < 0.5)
    return np.select(
        [sign, barrel, barricade],
        [ClusterKind.SIGN, ClusterKind.BARREL, ClusterKind.BARRICADE],
        ClusterKind.OTHER,
    ).astype(np.int64)
