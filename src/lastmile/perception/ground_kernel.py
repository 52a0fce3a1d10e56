"""Compiled per-region passes of the adaptive-grid ground fit (Numba).

One ring of the grid at a time: the points' residuals above their region's plane, and the weighted
sums of the region's plane fit. Each sum is added in point order, as ``np.bincount`` adds its
weights, with the same products (``w * x`` first, then ``(w * x) * y`` ...), so the planes come out
bit-identical to the NumPy version's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

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
