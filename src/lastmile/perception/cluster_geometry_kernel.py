"""Compiled per-cluster hull and box loops of :mod:`lastmile.perception.cluster_geometry` (Numba).

Points are grouped by cluster (``starts``, ``counts``). Every kernel does, one cluster at a time,
the arithmetic the NumPy version did on whole arrays, in the same order and with the same
comparisons (first index at a maximum or minimum wins), so the outputs are bit-identical. Sines and
cosines are computed by the caller with NumPy and passed in: libm's and NumPy's may differ in the
last bit.
"""

from __future__ import annotations

import numpy as np

from lastmile.perception.jit_cache import njit


@njit(cache=True, nogil=True, inline="always")
def _extend_box(
    c: float, s: float, px: float, py: float, u0: float, u1: float, v0: float, v1: float
) -> tuple[float, float, float, float]:
    """The box ``u0 u1 v0 v1`` along axes u = (c, s), v = (-s, c) grown to take the point (px, py)."""
    u = c * px + s * py
    v = -s * px + c * py
    return min(u0, u), max(u1, u), min(v0, v), max(v1, v)


@njit(cache=True, nogil=True)
def _support(
    x: np.ndarray,
    y: np.ndarray,
    cand: np.ndarray,
    n_cand: int,
    cos: np.ndarray,
    sin: np.ndarray,
    out: np.ndarray,
) -> None:
    """``out[j]``: the first of ``cand[:n_cand]`` farthest along direction j.

    One pass over the candidates for all directions (each direction's comparisons in candidate
    order, as a pass per direction makes them): the directions' running maxima are independent,
    so they proceed side by side instead of one dependent chain at a time.
    """
    n_dir = cos.shape[0]
    best = np.full(n_dir, -np.inf)
    first = cand[0]
    for j in range(n_dir):
        out[j] = first
    for q in range(n_cand):
        i = cand[q]
        xi, yi = x[i], y[i]
        for j in range(n_dir):
            v = xi * cos[j] + yi * sin[j]
            if v > best[j]:
                best[j] = v
                out[j] = i


@njit(cache=True, nogil=True)
def hull_support(
    x: np.ndarray,
    y: np.ndarray,
    starts: np.ndarray,
    counts: np.ndarray,
    filters: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    cos: np.ndarray,
    sin: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Support points of every cluster, after Akl-Toussaint filtering.

    Args:
        x, y: (N,) float64 point coordinates, grouped by cluster.
        starts, counts: (K,) int64 first point and size of each cluster (sizes >= 1).
        filters: (cos, sin) of the filter polygons' directions (4 then 8): points strictly
            inside the polygon of a cluster's support points cannot be hull vertices.
        cos, sin: (D,) the hull's directions.

    Returns:
        (K, D) int64 index of the first candidate farthest along each direction, and (N,) bool
        the candidates left by the filters (they hold every hull vertex).
    """
    n_cl = starts.shape[0]
    D = cos.shape[0]
    hull = np.empty((n_cl, D), np.int64)
    is_cand = np.zeros(x.shape[0], np.bool_)
    buf = np.empty(counts.max(), np.int64)
    for k in range(n_cl):
        n_cand = counts[k]
        for q in range(n_cand):
            buf[q] = starts[k] + q
        for f in range(2):
            fcos, fsin = filters[f]
            n_dir = fcos.shape[0]
            poly = np.empty(n_dir, np.int64)
            _support(x, y, buf, n_cand, fcos, fsin, poly)
            kept = 0
            for q in range(n_cand):
                i = buf[q]
                qx, qy = x[i], y[i]
                inside = True
                for j in range(n_dir):
                    v = poly[j]
                    w = poly[j + 1] if j + 1 < n_dir else poly[0]  # no integer division per edge
                    ex, ey = x[w] - x[v], y[w] - y[v]
                    if not (ex * (qy - y[v]) - ey * (qx - x[v]) > 0):
                        inside = False
                        break
                if not inside:
                    buf[kept] = i
                    kept += 1
            n_cand = kept
        for q in range(n_cand):
            is_cand[buf[q]] = True
        _support(x, y, buf, n_cand, cos, sin, hull[k])
    return hull, is_cand


@njit(cache=True, nogil=True)
def calipers_pick(hull_x: np.ndarray, hull_y: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(K,) int64: per cluster the first edge direction whose axes give the smallest box area.

    Args:
        hull_x, hull_y: (K, D) hull polygon vertices.
        c, s: (K, E) cosine and sine of each candidate axis angle.
    """
    n_cl, D = hull_x.shape
    E = c.shape[1]
    out = np.empty(n_cl, np.int64)
    for k in range(n_cl):
        best = np.inf
        arg = 0
        for e in range(E):
            ce, se = c[k, e], s[k, e]
            u0, u1, v0, v1 = np.inf, -np.inf, np.inf, -np.inf
            for d in range(D):
                u0, u1, v0, v1 = _extend_box(ce, se, hull_x[k, d], hull_y[k, d], u0, u1, v0, v1)
            area = (u1 - u0) * (v1 - v0)
            if area < best:
                best = area
                arg = e
        out[k] = arg
    return out


@njit(cache=True, nogil=True)
def refine_pick(
    x: np.ndarray,
    y: np.ndarray,
    is_cand: np.ndarray,
    starts: np.ndarray,
    counts: np.ndarray,
    ca: np.ndarray,
    sa: np.ndarray,
) -> np.ndarray:
    """(K,) int64: per cluster the first of the angles (cosines ``ca``, sines ``sa``, (K, A)) whose
    axes give the smallest box around the cluster's candidate points."""
    n_cl, A = ca.shape
    out = np.empty(n_cl, np.int64)
    u0 = np.empty(A)
    u1 = np.empty(A)
    v0 = np.empty(A)
    v1 = np.empty(A)
    for k in range(n_cl):
        u0[:] = np.inf
        v0[:] = np.inf
        u1[:] = -np.inf
        v1[:] = -np.inf
        for i in range(starts[k], starts[k] + counts[k]):
            if not is_cand[i]:
                continue
            px, py = x[i], y[i]
            for a in range(A):
                u0[a], u1[a], v0[a], v1[a] = _extend_box(
                    ca[k, a], sa[k, a], px, py, u0[a], u1[a], v0[a], v1[a]
                )
        best = np.inf
        arg = 0
        for a in range(A):
            area = (u1[a] - u0[a]) * (v1[a] - v0[a])
            if area < best:
                best = area
                arg = a
        out[k] = arg
    return out


@njit(cache=True, nogil=True)
def box_extents(
    x: np.ndarray, y: np.ndarray, starts: np.ndarray, counts: np.ndarray, ck: np.ndarray, sk: np.ndarray
) -> np.ndarray:
    """(K, 4) float64 ``u_min u_max v_min v_max`` of each cluster's points along its axes
    u = (ck, sk), v = (-sk, ck)."""
    n_cl = starts.shape[0]
    out = np.empty((n_cl, 4))
    for k in range(n_cl):
        c, s = ck[k], sk[k]
        u0, u1, v0, v1 = np.inf, -np.inf, np.inf, -np.inf
        for i in range(starts[k], starts[k] + counts[k]):
            u0, u1, v0, v1 = _extend_box(c, s, x[i], y[i], u0, u1, v0, v1)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = u0, u1, v0, v1
    return out


@njit(cache=True, nogil=True)
def gather_by_cluster(
    p: np.ndarray, intensity: np.ndarray, lab: np.ndarray, row_of_label: np.ndarray, counts: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points of the kept clusters grouped by cluster row, in input order within a cluster.

    Args:
        p: (N, 3) points; intensity: (N,); lab: (N,) labels (negative: no cluster, skipped).
        row_of_label: (C,) int64 row of each label's cluster, -1 for a dropped cluster.
        counts: (K,) points per kept row.

    Returns:
        x, y, intensity (M,) in row order, starts (K,), z_min (K,), z_max (K,).
    """
    n_rows = counts.shape[0]
    starts = np.zeros(n_rows, np.int64)
    for k in range(1, n_rows):
        starts[k] = starts[k - 1] + counts[k - 1]
    m = starts[-1] + counts[-1]
    x = np.empty(m)
    y = np.empty(m)
    inten = np.empty(m)
    z0 = np.full(n_rows, np.inf)
    z1 = np.full(n_rows, -np.inf)
    fill = starts.copy()
    for i in range(lab.shape[0]):
        if lab[i] < 0:
            continue  # an unlabelled point (ground, noise, curb) of a whole cloud
        k = row_of_label[lab[i]]
        if k < 0:
            continue
        q = fill[k]
        fill[k] += 1
        x[q], y[q], inten[q] = p[i, 0], p[i, 1], intensity[i]
        z0[k] = min(z0[k], p[i, 2])
        z1[k] = max(z1[k], p[i, 2])
    return x, y, inten, starts, z0, z1


@njit(cache=True, nogil=True)
def cloud_cluster_sums(
    p: np.ndarray, lab: np.ndarray, unit: np.ndarray, unit_weight: np.ndarray, n_cl: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per label 0..n_cl-1 of the labelled points of a whole cloud (labels < 0 skipped): point
    count, sum of x, sum of y (added in point order, as ``np.bincount`` does), lowest z, and the
    weighted size: the sum of ``unit_weight[unit[i]]`` over its points, in point order too.

    Args:
        p: (N, 3) points; lab: (N,) int64 labels; unit: (N,) float32 sensor index of each point;
        unit_weight: (S,) weight of one return of each sensor.
    """
    count = np.zeros(n_cl, np.int64)
    sx = np.zeros(n_cl)
    sy = np.zeros(n_cl)
    zmin = np.full(n_cl, np.inf)
    size = np.zeros(n_cl)
    n_units = unit_weight.shape[0]
    for i in range(lab.shape[0]):
        c = lab[i]
        if c < 0:
            continue
        s = np.int64(unit[i])
        if s < 0 or s >= n_units:
            raise ValueError("cloud_cluster_sums: a sensor index outside the weights given")
        count[c] += 1
        sx[c] += p[i, 0]
        sy[c] += p[i, 1]
        zmin[c] = min(zmin[c], p[i, 2])
        size[c] += unit_weight[s]
    return count, sx, sy, zmin, size
