"""Exact Euclidean clustering (DBSCAN with min_samples=1) on a voxel grid, plus per-cluster geometry.

Two points share a cluster when a chain of points joins them with every link no longer than
``eps_m``: the partition scikit-learn's ``DBSCAN(eps, min_samples=1)`` returns, computed without
enumerating every neighbour pair. The grid has cells of side ``eps / sqrt(3)`` (a hair less), so any
two points in one cell are within ``eps`` and a cell is connected for free; two cells can only hold
linked points when their index offsets are at most 2 on every axis. The compiled kernel
(:mod:`lastmile.perception.clustering_kernel`) joins such cell pairs in a union-find, testing point
by point only pairs still in different components and stopping at the first link. The result is
exact: every cell pair that could hold a link is either already known connected or tested.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import MessageError
from lastmile.perception.clustering_kernel import (
    grid_cell_keys,
    grid_cluster_labels,
    radix_argsort,
    row_cell_keys,
)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def canonical_labels(labels: npt.ArrayLike) -> IntArray:
    """Relabel a partition so clusters are numbered 0, 1, ... in order of their first point.

    This is the numbering scikit-learn's DBSCAN uses with ``min_samples=1``, so two partitions are
    identical exactly when their canonical labels are equal arrays.
    """
    lab = np.asarray(labels)
    if lab.size == 0:
        return np.zeros(0, dtype=np.int64)
    uniq, first, inverse = np.unique(lab, return_index=True, return_inverse=True)
    rank = np.empty(len(uniq), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(uniq))
    return rank[inverse.ravel()]


def euclidean_cluster_labels(xyz_m: npt.ArrayLike, eps_m: float) -> IntArray:
    """Cluster labels (N,) int64 of the Euclidean clustering of ``xyz_m`` at link length ``eps_m``.

    Args:
        xyz_m: (N, 3) point coordinates in metres (any float dtype; computed in float64).
        eps_m: the link length; points at distance <= eps_m are linked (as in DBSCAN).

    Returns:
        (N,) int64 labels numbered in order of each cluster's first point (see
        :func:`canonical_labels`); identical to ``DBSCAN(eps_m, min_samples=1).fit(xyz).labels_``.

    Raises:
        MessageError: if the array is not (N, 3) finite or ``eps_m`` is not positive and finite.
    """
    pts = np.asarray(xyz_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise MessageError(f"euclidean_cluster_labels: expected (N, 3) points, got shape {pts.shape}")
    if not (math.isfinite(eps_m) and eps_m > 0.0):
        raise MessageError(f"euclidean_cluster_labels: expected a positive finite eps_m, got {eps_m}")
    n = pts.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if not np.isfinite(pts).all():
        raise MessageError("euclidean_cluster_labels: expected finite coordinates, got NaN or inf")
    # A hair under eps/sqrt(3): the cell diagonal stays strictly below eps despite rounding.
    side = eps_m / math.sqrt(3.0) * (1.0 - 1e-6)
    # Contiguous columns: the compiled kernel reads them one element at a time.
    cols = [np.ascontiguousarray(pts[:, i]) for i in range(3)]
    key, ny, nz = grid_cell_keys(cols[0], cols[1], cols[2], side)
    # Cells as contiguous runs (order inside a cell is irrelevant: labels are numbered by first
    # point): a radix sort of the non-negative keys, linear where argsort's is N log N.
    order = radix_argsort(key)
    labels: IntArray = grid_cluster_labels(cols[0], cols[1], cols[2], key, order, ny, nz, eps_m * eps_m)
    return labels


def euclidean_cluster_rows(xyz_m: np.ndarray, rows: np.ndarray, eps_m: float) -> IntArray:
    """:func:`euclidean_cluster_labels` of the points ``xyz_m[rows]``, the same labels to the bit,
    with the rows' coordinates gathered and their cells keyed in one compiled pass (no (M, 3) copy,
    no column copies).

    Args:
        xyz_m: (N, 3) float64 points (C order).
        rows: (M,) int64 rows to cluster.
        eps_m: the link length.

    Raises:
        MessageError: if ``eps_m`` is not positive and finite or a coordinate is not finite.
    """
    if not (math.isfinite(eps_m) and eps_m > 0.0):
        raise MessageError(f"euclidean_cluster_rows: expected a positive finite eps_m, got {eps_m}")
    if len(rows) == 0:
        return np.zeros(0, dtype=np.int64)
    side = eps_m / math.sqrt(3.0) * (1.0 - 1e-6)  # as euclidean_cluster_labels
    x, y, z, key, ny, nz, finite = row_cell_keys(
        np.ascontiguousarray(xyz_m, dtype=np.float64), np.asarray(rows, dtype=np.int64), side
    )
    if not finite:
        raise MessageError("euclidean_cluster_rows: expected finite coordinates, got NaN or inf")
    labels: IntArray = grid_cluster_labels(x, y, z, key, radix_argsort(key), ny, nz, eps_m * eps_m)
    return labels
