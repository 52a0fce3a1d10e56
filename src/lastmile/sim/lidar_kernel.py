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


@njit(cache=True, nogil=True, error_model="numpy")
def _nan_max(a: float, b: float) -> float:
    """``np.maximum`` of two scalars: NaN when either is NaN, ``b`` when they compare equal."""
    if a != a or b != b:
        return a + b
    return a if a > b else b


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
def spin_ranges(
    ang: np.ndarray,
    dist: np.ndarray,
    near_m: float,
    theta0_rad: float,
    counter_clockwise: bool,
    pad_rad: float,
    spin: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The column ranges that can see each primitive: (start, stop, primitive), (3P,) each.

    Args:
        ang: (P, M) map-frame azimuths of each primitive's bounding points from the sensor.
        dist: (P,) each primitive's nearest bounding point (m); nearer than ``near_m`` (or spanning
            more than 0.9 pi) it is seen from every column.
        theta0_rad: the first column's azimuth; counter_clockwise: the spin direction.
        pad_rad: slack added on both sides.
        spin: (C,) the columns' non-decreasing spin angles from the first.

    Returns:
        Three blocks of P ranges (the interval one turn back, as is, one turn on), block after block.
    """
    n_prim, n_pts = ang.shape
    n_col = spin.shape[0]
    two_pi = 2.0 * math.pi
    starts = np.empty(3 * n_prim, dtype=np.int64)
    stops = np.empty(3 * n_prim, dtype=np.int64)
    ids = np.empty(3 * n_prim, dtype=np.int64)
    for p in range(n_prim):
        ref = ang[p, 0]
        d_min = np.inf
        d_max = -np.inf
        for m in range(n_pts):
            d = (ang[p, m] - ref + math.pi) % two_pi - math.pi
            d_min = min(d_min, d)
            d_max = max(d_max, d)
        lo, hi = ref + d_min, ref + d_max
        near = dist[p] < near_m or hi - lo > 0.9 * math.pi
        if counter_clockwise:
            a, b = lo - theta0_rad, hi - theta0_rad
        else:
            a, b = theta0_rad - hi, theta0_rad - lo
        a, b = a - pad_rad, b + pad_rad
        shift = np.floor(a / two_pi) * two_pi
        a, b = a - shift, b - shift
        for j in range(3):
            k = j - 1.0
            s = np.searchsorted(spin, a + k * two_pi, side="left")
            e = np.searchsorted(spin, b + k * two_pi, side="right")
            if j == 1:
                if near:
                    s, e = 0, n_col
            elif near:
                e = s
            starts[j * n_prim + p] = s
            stops[j * n_prim + p] = e
            ids[j * n_prim + p] = p
    return starts, stops, ids


@njit(cache=True, nogil=True, error_model="numpy")
def wall_pairs(
    starts: np.ndarray,
    stops: np.ndarray,
    ids: np.ndarray,
    ox: np.ndarray,
    oy: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    p0x: np.ndarray,
    p0y: np.ndarray,
    ex_w: np.ndarray,
    ey_w: np.ndarray,
    len_w: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The (wall, column) pairs whose ray crosses the wall ahead, in range order.

    Args:
        starts, stops, ids: (R,) column ranges [start, stop) of wall ``ids`` (``column_ranges``).
        ox, oy, dx, dy: (C,) the columns' origins and horizontal unit directions.
        p0x, p0y, ex_w, ey_w, len_w: (S,) each wall's first end, its vector to the other, its length.

    Returns:
        (Q,) wall, column, horizontal range to the crossing (m) and the 2-D incidence cosine.
    """
    total = 0
    for j in range(starts.shape[0]):
        if stops[j] > starts[j]:
            total += stops[j] - starts[j]
    prim_out = np.empty(total, dtype=np.int64)
    col_out = np.empty(total, dtype=np.int64)
    r_out = np.empty(total)
    cos_out = np.empty(total)
    m = 0
    for j in range(starts.shape[0]):
        w = ids[j]
        ex, ey = ex_w[w], ey_w[w]
        for c in range(starts[j], stops[j]):
            wx, wy = p0x[w] - ox[c], p0y[w] - oy[c]
            denom = dx[c] * ey - dy[c] * ex
            ok = np.abs(denom) > 1e-12
            safe = denom if ok else 1.0
            r = (wx * ey - wy * ex) / safe
            u = (wx * dy[c] - wy * dx[c]) / safe
            if ok and u >= 0.0 and u <= 1.0 and r > 0.0:
                prim_out[m] = w
                col_out[m] = c
                r_out[m] = r
                cos_out[m] = np.abs(denom) / len_w[w]
                m += 1
    return prim_out[:m], col_out[:m], r_out[:m], cos_out[:m]


@njit(cache=True, nogil=True, error_model="numpy")
def _np_min(a: float, b: float) -> float:
    """``np.minimum`` of two numbers that are not NaN: the second when they compare equal."""
    return a if a < b else b


@njit(cache=True, nogil=True, error_model="numpy")
def _np_max(a: float, b: float) -> float:
    """``np.maximum`` of two numbers that are not NaN: the second when they compare equal."""
    return a if a > b else b


@njit(cache=True, nogil=True, error_model="numpy")
def _range_total(starts: np.ndarray, stops: np.ndarray) -> int:
    total = 0
    for j in range(starts.shape[0]):
        if stops[j] > starts[j]:
            total += stops[j] - starts[j]
    return total


@njit(cache=True, nogil=True, error_model="numpy")
def cylinder_pairs(
    starts: np.ndarray,
    stops: np.ndarray,
    ids: np.ndarray,
    ox: np.ndarray,
    oy: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    t_s: np.ndarray,
    cx0: np.ndarray,
    cy0: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    radius: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The (cylinder, column) pairs whose ray meets the (moving) cylinder ahead, in range order:
    cylinder, column, entry and exit distances (m), 2-D incidence cosine.

    Args:
        starts, stops, ids: (R,) column ranges of each cylinder (``column_ranges``).
        ox, oy, dx, dy, t_s: (C,) the columns' origins, directions and firing times (s).
        cx0, cy0, vx, vy, radius: (N,) each cylinder's centre at time 0, velocity and radius.
    """
    total = _range_total(starts, stops)
    prim_out = np.empty(total, dtype=np.int64)
    col_out = np.empty(total, dtype=np.int64)
    rin_out = np.empty(total)
    rout_out = np.empty(total)
    cos_out = np.empty(total)
    m = 0
    for j in range(starts.shape[0]):
        q = ids[j]
        rad = radius[q]
        for c in range(starts[j], stops[j]):
            rx = ox[c] - (cx0[q] + vx[q] * t_s[c])
            ry = oy[c] - (cy0[q] + vy[q] * t_s[c])
            b = rx * dx[c] + ry * dy[c]
            disc = b * b - (rx * rx + ry * ry - rad * rad)
            if not disc >= 0.0:
                continue
            sq = np.sqrt(disc)
            r_out = -b + sq
            if not r_out > 0.0:
                continue
            prim_out[m] = q
            col_out[m] = c
            rin_out[m] = -b - sq
            rout_out[m] = r_out
            cos_out[m] = sq / rad
            m += 1
    return prim_out[:m], col_out[:m], rin_out[:m], rout_out[:m], cos_out[:m]


@njit(cache=True, nogil=True, error_model="numpy")
def box_pairs(
    starts: np.ndarray,
    stops: np.ndarray,
    ids: np.ndarray,
    ox: np.ndarray,
    oy: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    t_s: np.ndarray,
    cx0: np.ndarray,
    cy0: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    cos_yaw: np.ndarray,
    sin_yaw: np.ndarray,
    half_length: np.ndarray,
    half_width: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The (box, column) pairs whose ray meets the (moving, oriented) box ahead, by the slab test in
    the box frame, in range order: box, column, entry and exit distances (m), 2-D incidence cosine.

    A ray parallel to a slab is inside it (both bounds infinite) or outside it (it never enters).
    """
    total = _range_total(starts, stops)
    prim_out = np.empty(total, dtype=np.int64)
    col_out = np.empty(total, dtype=np.int64)
    rin_out = np.empty(total)
    rout_out = np.empty(total)
    cos_out = np.empty(total)
    m = 0
    for j in range(starts.shape[0]):
        q = ids[j]
        cp, sp, hl, hw = cos_yaw[q], sin_yaw[q], half_length[q], half_width[q]
        for c in range(starts[j], stops[j]):
            px = ox[c] - (cx0[q] + vx[q] * t_s[c])
            py = oy[c] - (cy0[q] + vy[q] * t_s[c])
            lox, loy = cp * px + sp * py, -sp * px + cp * py
            ldx, ldy = cp * dx[c] + sp * dy[c], -sp * dx[c] + cp * dy[c]
            if ldx == 0.0:
                inside = np.abs(lox) <= hl
                tx_lo, tx_hi = (-np.inf, np.inf) if inside else (np.inf, -np.inf)
            else:
                tx1, tx2 = (-hl - lox) / ldx, (hl - lox) / ldx
                tx_lo, tx_hi = _np_min(tx1, tx2), _np_max(tx1, tx2)
            if ldy == 0.0:
                inside = np.abs(loy) <= hw
                ty_lo, ty_hi = (-np.inf, np.inf) if inside else (np.inf, -np.inf)
            else:
                ty1, ty2 = (-hw - loy) / ldy, (hw - loy) / ldy
                ty_lo, ty_hi = _np_min(ty1, ty2), _np_max(ty1, ty2)
            r_in = _np_max(tx_lo, ty_lo)
            r_out = _np_min(tx_hi, ty_hi)
            if not (r_out >= r_in and r_out > 0.0):
                continue
            prim_out[m] = q
            col_out[m] = c
            rin_out[m] = r_in
            rout_out[m] = r_out
            cos_out[m] = np.abs(ldx) if tx_lo > ty_lo else np.abs(ldy)
            m += 1
    return prim_out[:m], col_out[:m], rin_out[:m], rout_out[:m], cos_out[:m]


@njit(cache=True, nogil=True, error_model="numpy")
def _on_road(
    road: np.ndarray, x0: float, y0: float, width: int, height: int, res: float, x: float, y: float
) -> bool:
    """``GroundRaster.is_road`` of one point (False off the raster)."""
    c = np.int64(math.floor((x - x0) / res))
    r = np.int64(math.floor((y - y0) / res))
    if c < 0 or c >= width or r < 0 or r >= height:
        return False
    return road[r * width + c]


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
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
    points: np.ndarray,
) -> None:
    """Fills ``points`` (N, 6) float32 with the sweep: x, y, z in the sensor frame, intensity rounded
    (half to even) and clipped to 0..255, ring (channel by ascending elevation), time offset in us.
    (The caller allocates it, so that the array it hands to the sweep owns its data.)"""
    n = idx.shape[0]
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


def preload() -> None:
    """Load (or compile) every kernel for the argument types the simulator passes, on empty inputs:
    called when a :class:`lastmile.sim.lidar.LidarSimulator` is built, so a run's first sweep does not
    pay for it (with a warm cache, about 0.3 s of CPU)."""
    f8, i8, b1 = np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.bool_)
    i1 = np.zeros(0, dtype=np.int8)
    tan = np.zeros(1)
    spin_ranges(np.zeros((0, 2)), f8, 1.0, 0.0, False, 0.01, tan)
    wall_pairs(i8, i8, i8, f8, f8, f8, f8, f8, f8, f8, f8, f8)
    cylinder_pairs(i8, i8, i8, f8, f8, f8, f8, f8, f8, f8, f8, f8, f8)
    box_pairs(i8, i8, i8, f8, f8, f8, f8, f8, f8, f8, f8, f8, f8, f8, f8, f8)
    nearest_hits(0, 1, tan, 1.0, i8, i8, i8, f8, f8, f8, i8)
    road = np.zeros(1, dtype=np.bool_)
    ground_ranges(i8, 1, tan, f8, f8, f8, f8, 1.0, 0.15, 100.0, road, 0.0, 0.0, 1, 1, 0.1, 0, 1)
    returns(i8, 1, f8, i1, f8, i8, f8, tan, tan, i1, f8, b1, f8, f8, 1e-5, 0.5, 100.0)
    intensity(f8, f8, f8, b1, f8, f8)
    sweep_points(i8, 1, 1, 100_000, f8, f8, tan, tan, f8, f8, np.zeros((0, 6), dtype=np.float32))
