"""Exact Euclidean clustering (DBSCAN with min_samples=1) on a voxel grid, plus per-cluster geometry.

Two points share a cluster when a chain of points joins them with every link no longer than
``eps_m``: the partition scikit-learn's ``DBSCAN(eps, min_samples=1)`` returns, computed without
enumerating every neighbour pair. The grid has cells of side ``eps / sqrt(3)`` (a hair less), so any
two points in one cell are within ``eps`` and a cell is connected for free; two cells can only hold
linked points when their index offsets are at most 2 on every axis. Cell pairs are first joined by
a cheap test on one representative point per cell (the point nearest the cell centre); only the
pairs whose cells are then still in different components are tested point by point. The result is
exact: every cell pair that could hold a link is either already known connected or tested in full.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from lastmile.core.errors import MessageError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

# Pairwise point tests are done in chunks of this many pairs to bound memory (~50 MB per chunk).
_PAIR_CHUNK = 2_000_000


# Column offsets (dx, dy) in [-2, 2]^2 taken once per +/- pair: (0, 0) pairs a cell with the cells
# above it in its own column, the other 12 with every cell of a neighbouring column within 2 in z.
_COLUMN_OFFSETS = [o for o in itertools.product(range(-2, 3), repeat=2) if o >= (0, 0)]


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
    eps2 = eps_m * eps_m
    # A hair under eps/sqrt(3): the cell diagonal stays strictly below eps despite rounding.
    side = eps_m / math.sqrt(3.0) * (1.0 - 1e-6)
    # Contiguous columns: 1-D operations on them are much cheaper than on (N, 3) blocks and do
    # the same arithmetic.
    cols = [np.ascontiguousarray(pts[:, i]) for i in range(3)]
    lo = [float(c.min()) for c in cols]
    # +2: neighbour offsets never go negative
    cell = [np.floor((c - c_lo) / side).astype(np.int64) + 2 for c, c_lo in zip(cols, lo, strict=True)]
    dims = [int(c.max()) + 3 for c in cell]
    key = (cell[0] * dims[1] + cell[1]) * dims[2] + cell[2]
    order = np.argsort(key)  # order inside a cell is irrelevant: labels are renumbered at the end
    skey = key[order]
    is_first = np.empty(n, dtype=bool)
    is_first[0] = True
    np.not_equal(skey[1:], skey[:-1], out=is_first[1:])
    start = np.flatnonzero(is_first)
    ukeys = skey[start]
    n_cells = len(ukeys)
    count = np.diff(np.append(start, n))
    cell_of_sorted = np.cumsum(is_first) - 1
    scols = [c[order] for c in cols]  # coordinates in cell order, one contiguous column each

    # Representative of each cell: its point nearest the cell centre (most likely to reach neighbours).
    d_centre = np.zeros(n)
    for sc, ci, c_lo in zip(scols, cell, lo, strict=True):
        d_centre += (sc - ((ci[order] - 2 + 0.5) * side + c_lo)) ** 2
    # Points are already grouped by cell: a segment reduction finds each cell's nearest distance,
    # and the first point at it is the first at-minimum index at or after the cell's start.
    nearest = np.minimum.reduceat(d_centre, start)
    at_min = np.flatnonzero(d_centre == nearest[cell_of_sorted])
    rep_idx = order[at_min[np.searchsorted(at_min, start)]]
    rep = [c[rep_idx] for c in cols]

    pa, pb, adjacent = _neighbour_cell_pairs(ukeys, int(dims[2]), int(dims[1]))

    # Pass 1: adjacent cells (offsets <= 1 on every axis) whose representatives are linked are
    # certainly connected. Cells two apart have centres >= 1.15 eps apart: their representatives
    # almost never link, so they go straight to pass 2 when still in different components.
    ra, rb = pa[adjacent], pb[adjacent]
    d0, d1, d2 = (c[ra] - c[rb] for c in rep)
    near = (d0 * d0 + d1 * d1 + d2 * d2) <= eps2
    la, lb = ra[near], rb[near]
    comp = _components(n_cells, la, lb)

    # Pass 2: every remaining pair of cells still in different components is tested point by point.
    open_ = comp[pa] != comp[pb]
    qa, qb = pa[open_], pb[open_]
    if len(qa):
        joined = _cells_linked(scols, start, count, qa, qb, eps2)
        if joined.any():
            comp = _components(n_cells, np.concatenate([la, qa[joined]]), np.concatenate([lb, qb[joined]]))
    labels = np.empty(n, dtype=np.int64)
    # Canonical numbering (by each cluster's first point) from per-cell minima, without sorting N.
    n_comp = int(comp.max()) + 1
    first = np.full(n_comp, n, dtype=np.int64)
    np.minimum.at(first, comp, np.minimum.reduceat(order, start))
    rank = np.empty(n_comp, dtype=np.int64)
    rank[np.argsort(first)] = np.arange(n_comp)
    labels[order] = rank[comp][cell_of_sorted]
    return labels


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # CSR with float64 weights is what connected_components works on: built so, it is not
    # converted again (about half the cost of an int8 COO graph).
    graph = csr_matrix((np.ones(len(a)), (a, b)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    return comp.astype(np.int64)


def _cells_linked(
    scols: list[FloatArray], start: np.ndarray, count: np.ndarray, qa: np.ndarray, qb: np.ndarray, eps2: float
) -> np.ndarray:
    """(P,) bool: whether cells qa[i] and qb[i] hold a pair of points within sqrt(eps2)."""
    na, nb = count[qa], count[qb]
    work = na * nb
    out = np.zeros(len(qa), dtype=bool)
    ends = np.cumsum(work)
    lo = 0
    while lo < len(qa):
        base = ends[lo - 1] if lo else 0
        hi = int(np.searchsorted(ends, base + _PAIR_CHUNK, side="right"))
        hi = max(hi, lo + 1)
        w = work[lo:hi]
        pair = np.repeat(np.arange(lo, hi), w)
        k = np.arange(int(w.sum())) - np.repeat(np.cumsum(w) - w, w)
        nbp = nb[pair]
        ia = start[qa[pair]] + k // nbp
        ib = start[qb[pair]] + k % nbp
        # Per column: the same differences and sum as on (n, 3) rows, without the row gathers.
        d0, d1, d2 = (sc[ia] - sc[ib] for sc in scols)
        hit = (d0 * d0 + d1 * d1 + d2 * d2) <= eps2
        out[lo:hi] = np.bincount(pair[hit] - lo, minlength=hi - lo) > 0
        lo = hi
    return out


def _neighbour_cell_pairs(ukeys: IntArray, nz: int, ny: int) -> tuple[IntArray, IntArray, np.ndarray]:
    """All pairs (a, b) of occupied cells whose index offsets are at most 2 on every axis, each once,
    and a bool per pair: offsets at most 1 on every axis (adjacent cells).

    Keys are ``(cx * ny + cy) * nz + cz``, so the cells of one column within 2 in z are one
    contiguous run of the sorted keys: two binary searches per column offset find every neighbour.
    """
    n_cells = len(ukeys)
    cells = np.arange(n_cells)
    pa_list, pb_list, adj_list = [], [], []
    for dx, dy in _COLUMN_OFFSETS:
        base = ukeys + (dx * ny + dy) * nz
        lo = np.searchsorted(ukeys, base + 1 if (dx, dy) == (0, 0) else base - 2, side="left")
        hi = np.searchsorted(ukeys, base + 2, side="right")
        n_hit = hi - lo
        has = n_hit > 0
        if not has.any():
            continue
        a = cells[has]
        n_hit = n_hit[has]
        pa_list.append(np.repeat(a, n_hit))
        first = np.repeat(lo[has] - (np.cumsum(n_hit) - n_hit), n_hit)
        b = first + np.arange(int(n_hit.sum()))
        pb_list.append(b)
        if abs(dx) <= 1 and abs(dy) <= 1:
            dz = ukeys[b] - np.repeat(base[has], n_hit)
            adj_list.append(np.abs(dz) <= 1)
        else:
            adj_list.append(np.zeros(len(b), dtype=bool))
    if not pa_list:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, np.zeros(0, dtype=bool)
    return (
        np.concatenate(pa_list).astype(np.int64),
        np.concatenate(pb_list).astype(np.int64),
        np.concatenate(adj_list),
    )
