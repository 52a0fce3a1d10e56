"""Compiled Euclidean clustering: union-find over the occupied cells of a voxel grid (Numba).

Cells have side ``< eps / sqrt(3)``, so any two points of one cell are linked and a cell is one
piece for free. Two cells can hold linked points only when their index offsets are at most 2 on
every axis; each such pair whose cells are not yet in one component is tested point by point, and
the test stops at the first linked pair. Every pair that could hold a link is either known
connected or tested, so the partition is exactly that of DBSCAN(eps, min_samples=1), with the
same squared-distance arithmetic ``(dx * dx + dy * dy) + dz * dz <= eps * eps`` as the NumPy code.
No fastmath (no reassociation): one input gives one partition, bit for bit.
"""

from __future__ import annotations

import numpy as np

from lastmile.perception.jit_cache import njit


@njit(cache=True, nogil=True)
def _find(parent: np.ndarray, a: int) -> int:
    # Path halving: every visited node points two levels up, so trees stay shallow.
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@njit(cache=True, nogil=True)
def grid_cell_keys(x: np.ndarray, y: np.ndarray, z: np.ndarray, side: float) -> tuple[np.ndarray, int, int]:
    """(N,) int64 cell key ``(cx * ny + cy) * nz + cz`` of every point, and ny, nz.

    Cell indices start at 2 and ``ny``, ``nz`` leave 2 spare cells above the last, so every index
    offset in [-2, 2] stays inside the grid and distinct cells never share a key.
    """
    n = x.shape[0]
    lo0, lo1, lo2 = x.min(), y.min(), z.min()
    cx = np.empty(n, np.int64)
    cy = np.empty(n, np.int64)
    cz = np.empty(n, np.int64)
    for i in range(n):
        cx[i] = np.int64(np.floor((x[i] - lo0) / side)) + 2
        cy[i] = np.int64(np.floor((y[i] - lo1) / side)) + 2
        cz[i] = np.int64(np.floor((z[i] - lo2) / side)) + 2
    ny = cy.max() + 3
    nz = cz.max() + 3
    return (cx * ny + cy) * nz + cz, ny, nz


@njit(cache=True, nogil=True)
def row_cell_keys(
    xyz: np.ndarray, rows: np.ndarray, side: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.int64, np.int64, bool]:
    """:func:`grid_cell_keys` of the points ``xyz[rows]`` (rows >= 1), with their x, y, z columns
    gathered in the same passes, and whether every coordinate is finite (when one is not, the
    keys are meaningless: the caller raises).

    Returns:
        x, y, z (M,) float64, keys (M,) int64, ny, nz, finite.
    """
    m = rows.shape[0]
    x = np.empty(m)
    y = np.empty(m)
    z = np.empty(m)
    lo0, lo1, lo2 = np.inf, np.inf, np.inf
    hi1, hi2 = -np.inf, -np.inf
    finite = True
    for q in range(m):
        i = rows[q]
        a, b, c = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        x[q], y[q], z[q] = a, b, c
        finite = finite and np.isfinite(a) and np.isfinite(b) and np.isfinite(c)
        lo0, lo1, lo2 = min(lo0, a), min(lo1, b), min(lo2, c)
        hi1, hi2 = max(hi1, b), max(hi2, c)
    key = np.zeros(m, np.int64)
    if not finite:
        return x, y, z, key, np.int64(0), np.int64(0), False
    # The cell formula is monotone in the coordinate: the largest index is the largest coordinate's.
    ny = np.int64(np.floor((hi1 - lo1) / side)) + 2 + 3
    nz = np.int64(np.floor((hi2 - lo2) / side)) + 2 + 3
    for q in range(m):
        cx = np.int64(np.floor((x[q] - lo0) / side)) + 2
        cy = np.int64(np.floor((y[q] - lo1) / side)) + 2
        cz = np.int64(np.floor((z[q] - lo2) / side)) + 2
        key[q] = (cx * ny + cy) * nz + cz
    return x, y, z, key, ny, nz, True


@njit(cache=True, nogil=True)
def grid_cluster_labels(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    key: np.ndarray,
    order: np.ndarray,
    ny: int,
    nz: int,
    eps2: float,
) -> np.ndarray:
    """(N,) int64 canonical cluster labels (numbered by each cluster's first point).

    Args:
        x, y, z: (N,) float64 coordinates, N >= 1, all finite.
        key, ny, nz: the points' cells from :func:`grid_cell_keys` with a side strictly below
            eps / sqrt(3) (a cell's diagonal below eps).
        order: (N,) int64 an ordering of the points by ``key`` (NumPy's argsort: several times
            faster than the compiled one).
        eps2: squared link length (m^2).
    """
    n = x.shape[0]
    sx = np.empty(n)
    sy = np.empty(n)
    sz = np.empty(n)
    skey = np.empty(n, np.int64)
    for i in range(n):
        o = order[i]
        sx[i] = x[o]
        sy[i] = y[o]
        sz[i] = z[o]
        skey[i] = key[o]
    # Occupied cells: start of each run of equal keys in sorted order.
    start = np.empty(n + 1, np.int64)
    n_cells = 0
    for i in range(n):
        if i == 0 or skey[i] != skey[i - 1]:
            start[n_cells] = i
            n_cells += 1
    start[n_cells] = n
    ukeys = np.empty(n_cells, np.int64)
    # Bounding box of each cell's points: a pair of cells, or a point and a cell, whose boxes are
    # farther apart than eps cannot link (the gap never exceeds a true point distance, even
    # rounded), so most point tests of a non-linking pair are skipped.
    box = np.empty((n_cells, 6))
    for c in range(n_cells):
        ukeys[c] = skey[start[c]]
        i0 = start[c]
        box[c, 0], box[c, 1], box[c, 2] = sx[i0], sy[i0], sz[i0]
        box[c, 3], box[c, 4], box[c, 5] = sx[i0], sy[i0], sz[i0]
        for i in range(i0 + 1, start[c + 1]):
            box[c, 0] = min(box[c, 0], sx[i])
            box[c, 1] = min(box[c, 1], sy[i])
            box[c, 2] = min(box[c, 2], sz[i])
            box[c, 3] = max(box[c, 3], sx[i])
            box[c, 4] = max(box[c, 4], sy[i])
            box[c, 5] = max(box[c, 5], sz[i])
    parent = np.arange(n_cells)
    # The 13 column offsets (dx, dy) >= (0, 0) lexicographically: each unordered pair of columns
    # once; (0, 0) pairs a cell with the cells above it in its own column.
    offsets = np.empty(13, np.int64)
    o = 0
    for dx in range(0, 3):
        for dy in range(-2, 3):
            if dx > 0 or dy >= 0:
                offsets[o] = (dx * ny + dy) * nz
                o += 1
    # Keys rise with the cell, so each offset's first candidate only moves forward: one merge-like
    # pointer per offset instead of a binary search per cell and offset.
    ptr = np.zeros(13, np.int64)
    for a in range(n_cells):
        ka = ukeys[a]
        for o in range(13):
            base = ka + offsets[o]
            first = base + 1 if o == 0 else base - 2
            b = ptr[o]
            while b < n_cells and ukeys[b] < first:
                b += 1
            ptr[o] = b
            while b < n_cells and ukeys[b] <= base + 2:
                ra = _find(parent, a)
                rb = _find(parent, b)
                if ra != rb and _cells_linked(sx, sy, sz, start, box, a, b, eps2):
                    parent[rb] = ra
                b += 1
    # Canonical numbering: clusters in order of their first point in the input order.
    cell_of_sorted = np.empty(n, np.int64)
    for c in range(n_cells):
        for i in range(start[c], start[c + 1]):
            cell_of_sorted[i] = c
    cell_of = np.empty(n, np.int64)
    for i in range(n):
        cell_of[order[i]] = cell_of_sorted[i]
    rank = np.full(n_cells, -1, np.int64)
    labels = np.empty(n, np.int64)
    next_label = 0
    for i in range(n):
        r = _find(parent, cell_of[i])
        if rank[r] < 0:
            rank[r] = next_label
            next_label += 1
        labels[i] = rank[r]
    return labels


@njit(cache=True, nogil=True)
def _gap2(box: np.ndarray, c: int, px: float, py: float, pz: float) -> float:
    """Squared distance from a point to cell ``c``'s box (0 inside)."""
    gx = max(box[c, 0] - px, px - box[c, 3], 0.0)
    gy = max(box[c, 1] - py, py - box[c, 4], 0.0)
    gz = max(box[c, 2] - pz, pz - box[c, 5], 0.0)
    return gx * gx + gy * gy + gz * gz


@njit(cache=True, nogil=True)
def _cells_linked(
    sx: np.ndarray,
    sy: np.ndarray,
    sz: np.ndarray,
    start: np.ndarray,
    box: np.ndarray,
    a: int,
    b: int,
    eps2: float,
) -> bool:
    """Whether cells ``a`` and ``b`` hold a pair of points within sqrt(eps2) (stops at the first)."""
    gx = max(box[b, 0] - box[a, 3], box[a, 0] - box[b, 3], 0.0)
    gy = max(box[b, 1] - box[a, 4], box[a, 1] - box[b, 4], 0.0)
    gz = max(box[b, 2] - box[a, 5], box[a, 2] - box[b, 5], 0.0)
    if gx * gx + gy * gy + gz * gz > eps2:
        return False
    for i in range(start[a], start[a + 1]):
        xi, yi, zi = sx[i], sy[i], sz[i]
        if _gap2(box, b, xi, yi, zi) > eps2:
            continue
        for j in range(start[b], start[b + 1]):
            dx = xi - sx[j]
            dy = yi - sy[j]
            dz = zi - sz[j]
            if dx * dx + dy * dy + dz * dz <= eps2:
                return True
    return False


@njit(cache=True, nogil=True)
def radix_argsort(key: np.ndarray) -> np.ndarray:
    """(N,) int64 permutation sorting the non-negative int64 ``key`` (stable LSD radix sort, 16 bits
    a pass, as many passes as the largest key needs): O(N) where a comparison sort is O(N log N)."""
    n = key.shape[0]
    order = np.arange(n)
    if n == 0:
        return order
    top = key.max()
    tmp = np.empty(n, np.int64)
    count = np.zeros(65_537, np.int64)
    shift = 0
    # Passes while the largest key has bits left (a shift by 64 is undefined: stop at 48).
    while shift == 0 or (shift < 64 and (top >> shift) > 0):
        count[:] = 0
        for q in range(n):
            count[((key[order[q]] >> shift) & 0xFFFF) + 1] += 1
        for c in range(65_536):
            count[c + 1] += count[c]
        for q in range(n):
            d = (key[order[q]] >> shift) & 0xFFFF
            tmp[count[d]] = order[q]
            count[d] += 1
        order, tmp = tmp, order
        shift += 16
    return order
