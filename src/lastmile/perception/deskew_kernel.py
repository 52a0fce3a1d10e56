"""Compiled per-point loops of the merge (Numba): de-skew time bins and per-bin rigid transforms,
the extrinsic transform of a sweep that is not de-skewed, and the pipeline's crop.

The arithmetic is that of the NumPy version, in float32 for the points (``((r0 * x + r1 * y) +
r2 * z) + t``, no fused multiply-add: Numba without fastmath does not contract), so the merged
clouds are bit-identical; the crop compares float32 coordinates with float32 bounds, as NumPy
compares a float32 array with a Python float.
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


@njit(cache=True, nogil=True)
def rigid_transform_into(p: np.ndarray, Bf: np.ndarray, out: np.ndarray, row: int, sensor_index: int) -> None:
    """Writes one sweep into ``out[row : row + N]``: ``Bf[:3, :3] @ p + Bf[:3, 3]`` in float32
    (``((b0 * x + b1 * y) + b2 * z) + t``), intensity and ring copied, the sensor index.

    Args:
        p: (N, >= 5) float32 sweep points (x y z intensity ring ...).
        Bf: (4, 4) float32 extrinsic.
        out: (M, 6) float32 merged cloud, written in place.
    """
    for i in range(p.shape[0]):
        x, y, z = p[i, 0], p[i, 1], p[i, 2]
        o = row + i
        for r in range(3):
            out[o, r] = x * Bf[r, 0] + y * Bf[r, 1] + z * Bf[r, 2] + Bf[r, 3]
        out[o, 3] = p[i, 3]
        out[o, 4] = p[i, 4]
        out[o, 5] = np.float32(sensor_index)


@njit(cache=True, nogil=True)
def crop_points(
    points: np.ndarray, box: np.ndarray, ego: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points inside the region of interest and outside the ego body, in one pass.

    Args:
        points: (N, C) float32 cloud (x y z first).
        box: float32 ``x_min, x_max, half_width, z_max`` of the kept region.
        ego: float32 ``x_min, x_max, half_width`` of the ego body.

    Returns:
        (M,) int64 rows kept, (M, C) float32 those rows, (M, 3) float64 their coordinates.
    """
    n, cols = points.shape
    rows = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        x, z = points[i, 0], points[i, 2]
        ay = abs(points[i, 1])
        inside = x >= box[0] and x <= box[1] and ay <= box[2] and z <= box[3]
        body = x >= ego[0] and x <= ego[1] and ay <= ego[2]
        if inside and not body:
            rows[m] = i
            m += 1
    kept = np.empty((m, cols), np.float32)
    xyz = np.empty((m, 3))
    for q in range(m):
        i = rows[q]
        for c in range(cols):
            kept[q, c] = points[i, c]
        for c in range(3):
            xyz[q, c] = np.float64(points[i, c])
    return rows[:m].copy(), kept, xyz
