"""Compiled per-ray passes of the simulated LiDAR (Numba): nearest prism hit, ground, returns, points.

Each pass replaces a chain of NumPy array operations over the sweep's rays with one loop that does,
per ray, the same IEEE operations in the same order (no fast-math, no fused multiply-add), so the
sweeps come out bit-identical to the NumPy version's. Transcendental functions (cos, sin, exp) and
every random draw stay in NumPy, outside the kernels: NumPy's SIMD versions of the former need not
round as libm does, and the draws must keep their order and sizes.

The kernels are cached in the user's cache folder like the perception kernels (``lastmile warmup``
compiles them ahead of the first run: :func:`lastmile.sim.lidar_warmup.warm_up`).
"""

from __future__ import annotations

import math
import os

import numba
import numpy as np
from numba import njit

from lastmile.core.user_cache import kernel_cache_dir

# The folder is chosen before the first kernel is decorated (Numba picks a function's cache locator
# at decoration); NUMBA_CACHE_DIR, when the user sets it, is respected as is.
if not os.environ.get("NUMBA_CACHE_DIR"):
    numba.config.CACHE_DIR = str(kernel_cache_dir())


@njit(cache=True, nogil=True)
def _nan_max(a: float, b: float) -> float:
    """``np.maximum`` of two scalars: NaN when either is NaN, ``b`` when they compare equal."""
    if a != a or b != b:
        return a + b
    return a if a > b else b


@njit(cache=True, nogil=True)
def nearest_hits(
    n_col: int,
    n_ch: int,
    tan_el: np.ndarray,
    oz: float,
    col: np.ndarray,
    k0: np.ndarray,
    k1: np.ndarray,
    r_in: np.ndarray,
    z_hi: np.ndarray,
    cos2d: np.ndarray,
    prim: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hit of every (column, channel) ray over the (pair, channel) cells the pairs span.

    Per cell, as ``np.minimum.at`` over the cells in pair order then channel order: the minimum
    horizontal range (NaN once any candidate is NaN); the winner is the last candidate equal to it.

    Args:
        n_col, n_ch: the sweep's columns and channels.
        tan_el: (K,) ascending tangents of the channels' elevations.
        oz: sensor height (m).
        col, k0, k1, r_in, z_hi, cos2d, prim: (Q,) per pair: its column, the channel interval
            [k0, k1) it meets, its entry distance (> 0), the prism's top, the 2-D incidence cosine
            and the primitive's index in the table.

    Returns:
        (C*K,) float64 range (inf: no hit), (C*K,) int64 primitive (-1: none), (C*K,) float64 cosine
        of incidence (1 where nothing was hit).
    """
    n = n_col * n_ch
    best = np.full(n, np.inf)
    win_pair = np.full(n, -1, dtype=np.int64)
    win_top = np.zeros(n, dtype=np.bool_)
    for p in range(col.shape[0]):
        rin = r_in[p]
        zh = z_hi[p]
        base = col[p] * n_ch
        for k in range(k0[p], k1[p]):
            tk = tan_el[k]
            top = oz + tk * rin > zh
            # Over the top at entry: the ray descends onto the top face.
            r = (zh - oz) / (-1e-12 if tk == 0.0 else tk) if top else rin
            f = base + k
            b = best[f]
            if b != b:
                continue  # NaN stays NaN (np.minimum)
            if r != r:
                best[f] = r
                win_pair[f] = -1
            elif r <= b:
                best[f] = r
                win_pair[f] = p
                win_top[f] = top
    prim_out = np.full(n, -1, dtype=np.int64)
    cos_out = np.ones(n)
    for f in range(n):
        p = win_pair[f]
        if p < 0:
            continue
        tk = tan_el[f % n_ch]
        cos_el = 1.0 / np.sqrt(1.0 + tk * tk)
        prim_out[f] = prim[p]
        cos_out[f] = np.abs(tk) * cos_el if win_top[f] else cos2d[p] * cos_el
    return best, prim_out, cos_out


@njit(cache=True, nogil=True)
def _on_road(
    road: np.ndarray, x0: float, y0: float, width: int, height: int, res: float, x: float, y: float
) -> bool:
    """``GroundRaster.is_road`` of one point (False off the raster)."""
    c = np.int64(math.floor((x - x0) / res))
    r = np.int64(math.floor((y - y0) / res))
    if c < 0 or c >= width or r < 0 or r >= height:
        return False
    return road[r * width + c]


@njit(cache=True, nogil=True)
def ground_ranges(
    cand: np.ndarray,
    n_ch: int,
    tan_el: np.ndarray,
    ox: np.ndarray,
    oy: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    oz: float,
    curb_height_m: float,
    max_range_m: float,
    road: np.ndarray,
    x0: float,
    y0: float,
    width: int,
    height: int,
    res: float,
    road_label: int,
    sidewalk_label: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal distance to the ground (inf: not downward) and its label for the rays ``cand``
    (flat column * K + channel): the road plane where it is met on road (or beyond the range), the
    raised sidewalk plane where it is met off road, else the road plane (a curb face, cast apart).

    Args:
        ox, oy, dx, dy: (C,) the columns' origins and horizontal unit directions.
        road: the raster's road mask, flattened (row-major, ``width`` columns).
    """
    n = cand.shape[0]
    r = np.full(n, np.inf)
    label = np.full(n, road_label, dtype=np.int8)
    raised = oz > curb_height_m
    for i in range(n):
        c = cand[i] // n_ch
        t = tan_el[cand[i] % n_ch]
        if not t < 0.0:
            continue
        r0 = -oz / t
        on_road = r0 > max_range_m or _on_road(
            road, x0, y0, width, height, res, ox[c] + r0 * dx[c], oy[c] + r0 * dy[c]
        )
        if on_road:
            r[i] = r0
            continue
        rs = (curb_height_m - oz) / t if raised else r0
        if _on_road(road, x0, y0, width, height, res, ox[c] + rs * dx[c], oy[c] + rs * dy[c]):
            r[i] = r0
        else:
            r[i] = rs
            label[i] = sidewalk_label
    return r, label


@njit(cache=True, nogil=True)
def returns(
    cand: np.ndarray,
    n_ch: int,
    ground_r: np.ndarray,
    ground_label: np.ndarray,
    hit_r: np.ndarray,
    hit_prim: np.ndarray,
    hit_cos: np.ndarray,
    cos_el: np.ndarray,
    sin_el: np.ndarray,
    table_label: np.ndarray,
    table_refl: np.ndarray,
    table_retro: np.ndarray,
    ground_refl: np.ndarray,
    loss: np.ndarray,
    threshold: float,
    min_range_m: float,
    max_range_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidate rays that return, nearest of ground and prism, above the detection threshold.

    Args:
        cand: (M,) flat ray indices (column * K + channel) that may return, ascending.
        ground_r, ground_label: (M,) the ground's horizontal range and label per candidate.
        hit_r, hit_prim, hit_cos: (C*K,) the nearest prism hit of every ray.
        cos_el, sin_el: (K,) of the channels' elevations.
        table_label, table_refl, table_retro: (P + 1,) per primitive (the last row: "none").
        ground_refl: reflectivity by ground label.
        loss: (M,) the atmosphere's two-way loss per candidate, or empty for clear air (1).

    Returns:
        For the returning rays, in ray order: flat index, range (m), cosine of incidence,
        reflectivity, retro-reflective, label (int8) and primitive (-1: ground).
    """
    n = cand.shape[0]
    idx = np.empty(n, dtype=np.int64)
    rng_out = np.empty(n)
    cos_out = np.empty(n)
    refl_out = np.empty(n)
    retro_out = np.empty(n, dtype=np.bool_)
    label_out = np.empty(n, dtype=np.int8)
    prim_out = np.empty(n, dtype=np.int64)
    clear = loss.shape[0] == 0
    m = 0
    for i in range(n):
        c = cand[i]
        ch = c % n_ch
        hr = hit_r[c]
        gr = ground_r[i]
        use_ground = gr < hr
        if use_ground:
            r_h = gr
            prim = -1
            label = ground_label[i]
            cos_inc = np.abs(sin_el[ch])
            refl = ground_refl[ground_label[i]]
            retro = False
        else:
            r_h = hr
            prim = hit_prim[c]
            label = table_label[prim]
            cos_inc = hit_cos[c]
            refl = table_refl[prim]
            retro = table_retro[prim]
        rng_m = r_h / cos_el[ch]
        power = refl if retro else refl * np.sqrt(_nan_max(cos_inc, 0.02))
        if not clear:
            power = power * loss[i]
        d = _nan_max(rng_m, 1e-3)
        power = power / (d * d)
        if power >= threshold and rng_m >= min_range_m and rng_m <= max_range_m:
            idx[m] = c
            rng_out[m] = rng_m
            cos_out[m] = cos_inc
            refl_out[m] = refl
            retro_out[m] = retro
            label_out[m] = label
            prim_out[m] = prim
            m += 1
    return idx[:m], rng_out[:m], cos_out[:m], refl_out[:m], retro_out[:m], label_out[:m], prim_out[:m]


@njit(cache=True, nogil=True)
def intensity(
    range_m: np.ndarray,
    cos_inc: np.ndarray,
    refl: np.ndarray,
    retro: np.ndarray,
    loss: np.ndarray,
    noise: np.ndarray,
) -> np.ndarray:
    """0..255 intensity before rounding (see ``lidar._intensity``); ``loss`` empty in clear air,
    ``noise`` the standard normal draws, one per return."""
    n = range_m.shape[0]
    out = np.empty(n)
    clear = loss.shape[0] == 0
    for i in range(n):
        c = cos_inc[i]
        shape = 0.85 + 0.1 * c if retro[i] else 0.3 + 0.7 * c
        value = 255.0 * refl[i] * shape
        if not clear:
            value = value * loss[i]
        q = range_m[i] / 150.0
        value = value / (1.0 + q * q)
        out[i] = value + noise[i] * (1.5 + 0.03 * value)
    return out


@njit(cache=True, nogil=True)
def sweep_points(
    idx: np.ndarray,
    n_ch: int,
    n_col: int,
    period_us: int,
    range_m: np.ndarray,
    intensity_raw: np.ndarray,
    cos_el: np.ndarray,
    sin_el: np.ndarray,
    cos_az: np.ndarray,
    sin_az: np.ndarray,
) -> np.ndarray:
    """(N, 6) float32 points of the sweep: x, y, z in the sensor frame, intensity rounded (half to
    even) and clipped to 0..255, ring (channel by ascending elevation), time offset in us."""
    n = idx.shape[0]
    points = np.empty((n, 6), dtype=np.float32)
    for i in range(n):
        col = idx[i] // n_ch
        ch = idx[i] % n_ch
        r = range_m[i]
        rc = r * cos_el[ch]
        points[i, 0] = rc * cos_az[col]
        points[i, 1] = rc * sin_az[col]
        points[i, 2] = r * sin_el[ch]
        # np.clip(np.round(v), 0, 255): NaN stays NaN, -0.0 stays -0.0.
        v = np.rint(intensity_raw[i])
        if v < 0.0:
            v = 0.0
        elif v > 255.0:
            v = 255.0
        points[i, 3] = v
        points[i, 4] = ch
        points[i, 5] = (col * period_us) // n_col
    return points
