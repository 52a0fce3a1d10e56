"""Compiled per-region passes of the adaptive-grid ground fit (Numba).

One ring of the grid at a time: the points' residuals above their region's plane, and the weighted
sums of the region's plane fit. Each sum is added in point order, as ``np.bincount`` adds its
weights, with the same products (``w * x`` first, then ``(w * x) * y`` ...), so the planes come out
bit-identical to the NumPy version's.
"""

from __future__ import annotations

import numpy as np

from lastmile.perception.jit_cache import njit

N_SUMS = 10
"""Columns of :func:`weighted_sums`: w, wx, wy, wz, wxx, wxy, wyy, wxz, wyz, count(w > 0)."""


@njit(cache=True, nogil=True)
def plane_residuals(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, region: np.ndarray, planes: np.ndarray
) -> np.ndarray:
    """(N,) height of every point above its region's plane ``z = a + b x + c y`` (planes (R, 3))."""
    res = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        r = region[i]
        res[i] = z[i] - (planes[r, 0] + planes[r, 1] * x[i] + planes[r, 2] * y[i])
    return res


@njit(cache=True, nogil=True)
def weighted_sums(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    res: np.ndarray,
    region: np.ndarray,
    n_regions: int,
    seed: bool,
    low: np.ndarray,
    window: np.ndarray,
    max_below_m: float,
    seed_window_m: float,
    seed_band_m: float,
) -> np.ndarray:
    """(R, N_SUMS) weighted sums of each region's plane fit.

    Args:
        x, y, z, res, region: (N,) the ring's points, their residuals and regions.
        seed: the first pass: weight 1 for points within ``seed_band_m`` of their region's
            ``low`` residual (and between ``-max_below_m`` and ``seed_window_m``), else 0.
            Otherwise Tukey weights ``(1 - (res / window)^2)^2`` inside ``|res| <= window``.
        low: (R,) the regions' seed reference residuals (used when ``seed``).
        window: (N,) the points' tolerances (used when not ``seed``).
    """
    out = np.zeros((n_regions, N_SUMS))
    for i in range(x.shape[0]):
        r = res[i]
        g = region[i]
        if seed:
            if not (r >= -max_below_m and r <= seed_window_m):
                continue
            rel = r - low[g]
            if not (rel >= -seed_band_m and rel <= seed_band_m):
                continue
            w = 1.0
        else:
            if not abs(r) <= window[i]:
                continue
            t = r / window[i]
            a = 1.0 - t * t
            w = a * a
        wx = w * x[i]
        wy = w * y[i]
        out[g, 0] += w
        out[g, 1] += wx
        out[g, 2] += wy
        out[g, 3] += w * z[i]
        out[g, 4] += wx * x[i]
        out[g, 5] += wx * y[i]
        out[g, 6] += wy * y[i]
        out[g, 7] += wx * z[i]
        out[g, 8] += wy * z[i]
        if w > 0:
            out[g, 9] += 1.0
    return out


@njit(cache=True, nogil=True)
def ring_points(
    idx: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    az: np.ndarray,
    tol: np.ndarray,
    road: np.ndarray,
    sector_rad: float,
    n_sec: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One ring's points gathered in one pass: x, y, z, tolerance, and region ``2 * sector + road``
    with ``sector = floor((az + pi) / sector_rad) mod n_sec`` (the array expression's arithmetic)."""
    m = idx.shape[0]
    px = np.empty(m)
    py = np.empty(m)
    pz = np.empty(m)
    window = np.empty(m)
    region = np.empty(m, np.int64)
    for q in range(m):
        i = idx[q]
        px[q] = x[i]
        py[q] = y[i]
        pz[q] = z[i]
        window[q] = tol[i]
        sec = np.int64(np.floor((az[i] + np.pi) / sector_rad))
        if sec < 0 or sec >= n_sec:  # only az = pi (or outside +-pi): the integer division is slow
            sec %= n_sec
        region[q] = sec * 2 + (1 if road[i] else 0)
    return px, py, pz, window, region


@njit(cache=True, nogil=True)
def low_quantile(
    res: np.ndarray,
    region: np.ndarray,
    n_regions: int,
    max_below_m: float,
    seed_window_m: float,
    bin_m: float,
    quantile: float,
) -> np.ndarray:
    """(R,) per-region ``quantile`` of the residuals within ``[-max_below_m, seed_window_m]``, from a
    histogram of ``bin_m`` bins (the bin's centre), as the array version computes it."""
    n_bins = int(np.ceil((max_below_m + seed_window_m) / bin_m)) + 1
    hist = np.zeros((n_regions, n_bins), np.int64)
    for i in range(res.shape[0]):
        r = res[i]
        if not (r >= -max_below_m and r <= seed_window_m):
            continue
        cell = min(max(int((r + max_below_m) / bin_m), 0), n_bins - 1)  # truncation, as astype
        hist[region[i], cell] += 1
    out = np.empty(n_regions)
    for g in range(n_regions):
        total = 0
        for j in range(n_bins):
            total += int(hist[g, j])
        target = max(total * quantile, 1.0)
        cum = 0
        k = 0
        for j in range(n_bins):
            cum += int(hist[g, j])
            if cum >= target:
                k = j
                break
        out[g] = (k + 0.5) * bin_m - max_below_m
    return out


@njit(cache=True, nogil=True)
def classify_ring(
    idx: np.ndarray,
    res: np.ndarray,
    region: np.ndarray,
    window: np.ndarray,
    n_regions: int,
    smooth_floor_m: float,
    smooth_sigmas: float,
    ground: np.ndarray,
    max_below_m: float,
) -> np.ndarray:
    """Marks ``ground[idx[q]]`` where the residual is within the point's tolerance, tightened per
    region to ``max(smooth_floor_m, smooth_sigmas * rms)`` of the region's inlier residuals.

    Returns:
        (n_regions,) int64 how many of each region's points lie more than ``max_below_m`` below
        its plane (``np.bincount(region[res < -max_below_m])``, counted in the same pass).
    """
    n_in = np.zeros(n_regions)
    ss = np.zeros(n_regions)
    below = np.zeros(n_regions, np.int64)
    for q in range(res.shape[0]):
        if abs(res[q]) <= window[q]:
            n_in[region[q]] += 1.0
            ss[region[q]] += res[q] * res[q]
        if res[q] < -max_below_m:
            below[region[q]] += 1
    smooth = np.empty(n_regions)
    for g in range(n_regions):
        smooth[g] = max(smooth_floor_m, smooth_sigmas * np.sqrt(ss[g] / max(n_in[g], 1.0)))
    for q in range(res.shape[0]):
        ground[idx[q]] = res[q] <= min(window[q], smooth[region[q]])
    return below


@njit(cache=True, nogil=True)
def plane_systems(sums: np.ndarray, prior: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """(R, 3, 3) normal matrices and (R, 3) right-hand sides of the regions' plane fits from their
    :func:`weighted_sums`, regularised toward ``prior`` (R, 3) with weight ``lam``: the array
    expressions ``A + lam * eye(3)`` and ``b + lam * prior`` element for element (``lam * 0.0``
    is added off the diagonal too, as the array form adds it)."""
    n = sums.shape[0]
    a = np.empty((n, 3, 3))
    b = np.empty((n, 3))
    on = lam * 1.0
    off = lam * 0.0
    for r in range(n):
        sw, sx, sy, sz = sums[r, 0], sums[r, 1], sums[r, 2], sums[r, 3]
        sxx, sxy, syy, sxz, syz = sums[r, 4], sums[r, 5], sums[r, 6], sums[r, 7], sums[r, 8]
        a[r, 0, 0], a[r, 0, 1], a[r, 0, 2] = sw + on, sx + off, sy + off
        a[r, 1, 0], a[r, 1, 1], a[r, 1, 2] = sx + off, sxx + on, sxy + off
        a[r, 2, 0], a[r, 2, 1], a[r, 2, 2] = sy + off, sxy + off, syy + on
        b[r, 0] = sz + lam * prior[r, 0]
        b[r, 1] = sxz + lam * prior[r, 1]
        b[r, 2] = syz + lam * prior[r, 2]
    return a, b


@njit(cache=True, nogil=True)
def accept_planes(
    sol: np.ndarray,
    slope: np.ndarray,
    sums: np.ndarray,
    prior: np.ndarray,
    min_fit_points: float,
    max_slope: float,
    max_step_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The regions' planes (R, 3) and (R,) whether each kept its own fit ``sol``.

    A fit is kept with at least ``min_fit_points`` points, a ``slope`` (its gradient's norm) within
    ``max_slope``, finite coefficients and a step from the prior, measured at the fitted points'
    centroid, within ``max_step_m``; otherwise the region takes its prior, or the fit of the other
    part of its cell (road / off-road, regions ``2 k`` and ``2 k + 1``) when that one kept its own.
    """
    n = sol.shape[0]
    ok = np.empty(n, np.bool_)
    for r in range(n):
        keep = sums[r, 9] >= min_fit_points and slope[r] <= max_slope
        keep = keep and np.isfinite(sol[r, 0]) and np.isfinite(sol[r, 1]) and np.isfinite(sol[r, 2])
        if sums[r, 0] == 0.0:
            # No weight: the centroid is 0/0 or x/0, so the array form's step is NaN or inf and
            # fails (and Numba's float division by zero would raise).
            ok[r] = False
            continue
        cx = sums[r, 1] / sums[r, 0]
        cy = sums[r, 2] / sums[r, 0]
        step = (sol[r, 0] - prior[r, 0]) + (sol[r, 1] - prior[r, 1]) * cx + (sol[r, 2] - prior[r, 2]) * cy
        ok[r] = keep and abs(step) <= max_step_m  # NaN and inf steps fail
    out = np.empty((n, 3))
    for r in range(n):
        src = sol if ok[r] else prior
        for c in range(3):
            out[r, c] = src[r, c]
    for k in range(n // 2):
        road, off_road = 2 * k + 1, 2 * k
        if not ok[off_road] and ok[road]:
            for c in range(3):
                out[off_road, c] = out[road, c]
        elif not ok[road] and ok[off_road]:
            for c in range(3):
                out[road, c] = out[off_road, c]
    return out, ok


@njit(cache=True, nogil=True)
def ring_prelude(
    x: np.ndarray,
    y: np.ndarray,
    edges: np.ndarray,
    near_m: float,
    per_m: float,
    max_m: float,
    n_rings: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One pass over the cloud: each point's ground tolerance, the points grouped by ring, and where
    each ring's group starts.

    The array expressions it replaces: ``r = np.hypot(x, y)`` (the same libm ``hypot``),
    ``tol = np.minimum(near_m + per_m * r, max_m)``, ``ring = (number of edges <= r) - 1``,
    ``by_ring = np.argsort(ring, kind="stable")`` (here a counting sort, stable too) and
    ``ring_start = np.searchsorted(ring[by_ring], np.arange(n_rings + 1))``.

    Returns:
        (N,) tol, (N,) int64 by_ring, (n_rings + 1,) int64 ring_start.
    """
    n = x.shape[0]
    n_edges = edges.shape[0]
    tol = np.empty(n)
    ring = np.empty(n, np.int64)
    # ring + 1 in 0 .. n_edges (-1 for a NaN range, which meets no edge)
    count = np.zeros(n_edges + 2, np.int64)
    for i in range(n):
        r = np.hypot(x[i], y[i])
        a = near_m + per_m * r
        tol[i] = a if (a <= max_m or np.isnan(a)) else max_m  # np.minimum: NaN kept, ties the first
        k = -1
        for e in range(n_edges):
            if r >= edges[e]:
                k += 1
        ring[i] = k
        count[k + 2] += 1
    for c in range(n_edges + 1):
        count[c + 1] += count[c]
    # count[k + 1] is now the first slot of ring k (the number of points with a smaller ring)
    ring_start = np.empty(n_rings + 1, np.int64)
    for k in range(n_rings + 1):
        ring_start[k] = count[min(k, n_edges) + 1]
    by_ring = np.empty(n, np.int64)
    for i in range(n):
        slot = ring[i] + 1
        by_ring[count[slot]] = i
        count[slot] += 1
    return tol, by_ring, ring_start
