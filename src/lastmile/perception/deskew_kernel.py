"""Compiled per-point loops of de-skewing (Numba): time bins and per-bin rigid transforms.

The arithmetic is that of the NumPy version, in float32 for the points (``((r0 * x + r1 * y) +
r2 * z) + t``, no fused multiply-add: Numba without fastmath does not contract), so the de-skewed
clouds are bit-identical.
"""

from __future__ import annotations

import numpy as np

from lastmile.perception.jit_cache import njit


@njit(cache=True, nogil=True)
def time_bins(stamp_us: int, t_offset_us: np.ndarray, time_bin_us: int) -> tuple[np.ndarray, int, int]:
    """(N,) int64 bin of each point's capture time ``stamp_us + int(t_offset_us)`` (N >= 1), the
    earliest such time and the number of bins."""
    n = t_offset_us.shape[0]
    t = np.empty(n, np.int64)
    t_lo: int = stamp_us + int(t_offset_us[0])
    for i in range(n):
        t[i] = stamp_us + np.int64(t_offset_us[i])  # truncation toward zero, as astype(int64)
        t_lo = min(t_lo, int(t[i]))
    n_bins = 0
    for i in range(n):
        t[i] = (t[i] - t_lo) // time_bin_us
        n_bins = max(n_bins, int(t[i]) + 1)
    return t, t_lo, n_bins


@njit(cache=True, nogil=True)
def bin_transforms(p: np.ndarray, bins: np.ndarray, Tc: np.ndarray) -> np.ndarray:
    """(N, 3) float32 ``T[bins] @ p`` for (N, >= 3) float32 points; ``Tc`` (12, n_bins) float32 holds
    the rows of each bin's (3, 4) transform, entry-major."""
    n = p.shape[0]
    out = np.empty((n, 3), np.float32)
    for i in range(n):
        b = bins[i]
        x, y, z = p[i, 0], p[i, 1], p[i, 2]
        for r in range(3):
            out[i, r] = Tc[4 * r, b] * x + Tc[4 * r + 1, b] * y + Tc[4 * r + 2, b] * z + Tc[4 * r + 3, b]
    return out
