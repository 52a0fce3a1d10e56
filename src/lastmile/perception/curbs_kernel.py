"""Compiled nearest-segment Frenet projection of points onto a polyline (Numba).

:func:`lastmile.perception.curbs.frenet_of_points` formed (N, M-1) arrays of every point against
every segment each frame (the closed loop's curb stage spent half its time there). This pass keeps
one running minimum per point instead, with the same arithmetic in the same order as those array
expressions (no fused multiply-add: Numba compiles without fast-math), and NumPy's ``argmin`` rule
(the first minimum wins; a NaN distance wins at once), so ``s`` and ``d`` are bit-identical.
"""

from __future__ import annotations

import math

import numpy as np

from lastmile.perception.jit_cache import njit


@njit(cache=True, nogil=True)
def frenet_nearest(
    x: np.ndarray,
    y: np.ndarray,
    ax: np.ndarray,
    ay: np.ndarray,
    tx: np.ndarray,
    ty: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    s0: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Station and left offset of every point on its nearest segment.

    Args:
        x, y: (N,) float64 points.
        ax, ay: (S,) float64 segment starts; tx, ty: (S,) unit directions.
        lo, hi: (S,) clip bounds of the along-segment coordinate (-inf / inf at the open ends).
        s0: (S,) station of each segment's start.

    Returns:
        (N,) s and (N,) d.
    """
    n, n_seg = x.shape[0], ax.shape[0]
    # Segment-major: one pass over the points per segment keeps every point's running nearest
    # (the inner loop over contiguous arrays compiles to vector code; ~3x the point-major loop).
    # Segments are visited in order and replace only on a strictly smaller distance: the first
    # minimum wins, as argmin's.
    best = np.empty(n)
    k = np.full(n, -1, np.int64)
    best_t = np.empty(n)
    best_rx = np.empty(n)
    best_ry = np.empty(n)
    for j in range(n_seg):
        axj, ayj, txj, tyj, loj, hij = ax[j], ay[j], tx[j], ty[j], lo[j], hi[j]
        for i in range(n):
            rx = x[i] - axj
            ry = y[i] - ayj
            along = rx * txj + ry * tyj
            # np.clip's float rule: max(a, lo) then min(., hi), each keeping the first operand
            # only when strictly beyond (so -0.0 clipped at 0.0 becomes 0.0), NaN kept.
            t = along
            if not math.isnan(t):
                t = t if t > loj else loj
                t = t if t < hij else hij
            px = axj + t * txj
            py = ayj + t * tyj
            ex = x[i] - px
            ey = y[i] - py
            d2 = ex * ex + ey * ey
            # np.argmin: the first minimum; the first NaN wins over everything.
            b = best[i]
            if k[i] < 0 or (not math.isnan(b) and (math.isnan(d2) or d2 < b)):
                best[i], k[i], best_t[i], best_rx[i], best_ry[i] = d2, j, t, rx, ry
    s = np.empty(n)
    d = np.empty(n)
    for i in range(n):
        kk = k[i]
        s[i] = s0[kk] + best_t[i]
        d[i] = tx[kk] * best_ry[i] - ty[kk] * best_rx[i]
    return s, d


@njit(cache=True, nogil=True)
def scatter_min(out: np.ndarray, index: np.ndarray, values: np.ndarray) -> None:
    """``np.minimum.at(out, index, values)`` in one compiled pass, with NumPy's rule per element:
    a NaN already there stays, else the new value unless the old one is strictly smaller (so a NaN
    value enters, and of two equal zeros the new one is kept)."""
    for i in range(index.shape[0]):
        j = index[i]
        cur = out[j]
        if not math.isnan(cur) and not cur < values[i]:
            out[j] = values[i]


@njit(cache=True, nogil=True)
def scatter_max(out: np.ndarray, index: np.ndarray, values: np.ndarray) -> None:
    """``np.maximum.at(out, index, values)`` in one compiled pass (NumPy's rule, as
    :func:`scatter_min` with the comparison reversed)."""
    for i in range(index.shape[0]):
        j = index[i]
        cur = out[j]
        if not math.isnan(cur) and not cur > values[i]:
            out[j] = values[i]
