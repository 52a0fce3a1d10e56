"""Compiled fixed-radius neighbour test of DROR on a bucket grid (Numba).

Each tested point needs ``k`` other points within its own radius. The candidate neighbours are
bucketed in a grid of side ``r_max`` (a hair more), so all points within ``r_max`` of a tested
point lie in the 3 x 3 x 3 cells around its own, and the count stops as soon as it reaches ``k``.
The distance is the one a SciPy ``cKDTree.query(..., distance_upper_bound=r_max)`` returns (squared
differences summed x, y, z in that order, then the square root; neighbours at ``r_max`` or
beyond excluded), so the mask equals that of the k-th-nearest-neighbour query bit for bit.
"""

from __future__ import annotations

import numpy as np

from lastmile.perception.jit_cache import njit

# A grid with more cells than this many per pooled point (plus a constant) is sorted instead of
# counted into buckets: a sparse pool spread far would make the bucket array larger than it saves.
_CELLS_PER_POINT = 16
_CELLS_SPARE = 65_536
# Cell-column offsets (x, y) of the neighbour search, the point's own first.
_RUN_ORDER_X = np.array([0, -1, -1, -1, 0, 0, 1, 1, 1], dtype=np.int64)
_RUN_ORDER_Y = np.array([0, -1, 0, 1, -1, 1, -1, 0, 1], dtype=np.int64)


@njit(cache=True, nogil=True)
def enough_neighbours(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    pool: np.ndarray,
    test: np.ndarray,
    radius: np.ndarray,
    r_max: float,
    k: int,
) -> np.ndarray:
    """(T,) bool: whether ``test[t]`` has at least ``k`` pool points other than itself within
    ``radius[test[t]]``.

    Args:
        x, y, z: (N,) float64 coordinates (m).
        pool: (P,) int64 indices of the points that may be neighbours; every tested point is one.
        test: (T,) int64 indices of the tested points.
        radius: (N,) float64 radius of every point (m), at most ``r_max`` for tested points.
        r_max: largest radius of a tested point (m).
        k: neighbours needed.
    """
    n_pool = pool.shape[0]
    side = r_max * (1.0 + 1e-6)  # a neighbour within r_max never lands two cells away despite rounding
    lo0, lo1, lo2 = np.inf, np.inf, np.inf
    hi0, hi1, hi2 = -np.inf, -np.inf, -np.inf
    for j in pool:
        lo0, hi0 = min(lo0, x[j]), max(hi0, x[j])
        lo1, hi1 = min(lo1, y[j]), max(hi1, y[j])
        lo2, hi2 = min(lo2, z[j]), max(hi2, z[j])
    # The cell formula is monotone in the coordinate, so the largest cell index is the largest
    # coordinate's (+1: room for the -1 neighbour offset; +2: for the +1 one and the count).
    ny = np.int64(np.floor((hi1 - lo1) / side)) + 3
    nz = np.int64(np.floor((hi2 - lo2) / side)) + 3
    n_keys = (np.int64(np.floor((hi0 - lo0) / side)) + 3) * ny * nz
    key = np.empty(n_pool, np.int64)
    for q in range(n_pool):
        j = pool[q]
        cx = np.int64(np.floor((x[j] - lo0) / side)) + 1
        cy = np.int64(np.floor((y[j] - lo1) / side)) + 1
        cz = np.int64(np.floor((z[j] - lo2) / side)) + 1
        key[q] = (cx * ny + cy) * nz + cz
    # Pool points grouped by cell (coordinates copied in that order): ``first[c]`` .. ``first[c + 1]``
    # when bucketed; for a grid too large for buckets, the sorted keys are searched instead.
    bucketed = n_keys <= _CELLS_PER_POINT * n_pool + _CELLS_SPARE
    if bucketed:
        # int32 offsets (a pool is far below 2**31 points): the bucket array is mostly empty
        # cells, and zeroing, summing and copying it is this kernel's largest memory traffic.
        first = np.zeros(n_keys + 1, np.int32)
        for q in range(n_pool):
            first[key[q] + 1] += 1
        for c in range(n_keys):
            first[c + 1] += first[c]
        fill = first[:-1].copy()
        order = np.empty(n_pool, np.int64)
        for q in range(n_pool):
            order[fill[key[q]]] = q
            fill[key[q]] += 1
        skey = np.empty(0, np.int64)
    else:
        first = np.empty(0, np.int32)
        order = np.argsort(key)
        skey = key[order]
    px = np.empty(n_pool)
    py = np.empty(n_pool)
    pz = np.empty(n_pool)
    for q in range(n_pool):
        j = pool[order[q]]
        px[q], py[q], pz[q] = x[j], y[j], z[j]
    r_max2 = r_max * r_max
    out = np.zeros(test.shape[0], np.bool_)
    for t in range(test.shape[0]):
        i = test[t]
        xi, yi, zi, ri = x[i], y[i], z[i], radius[i]
        # Squared bounds a relative 1e-12 either side of ri^2 (far wider than any rounding of the
        # squares): below the lower, sqrt(d2) <= ri surely holds; above the upper, surely not;
        # only between them is the square root taken (the verdict is the sqrt test's, bit for bit,
        # without a square root per candidate).
        ri2 = ri * ri
        in2, out2 = ri2 * (1.0 - 1e-12), ri2 * (1.0 + 1e-12)
        gx = (xi - lo0) / side
        gy = (yi - lo1) / side
        gz = (zi - lo2) / side
        ix = np.int64(np.floor(gx)) + 1
        iy = np.int64(np.floor(gy)) + 1
        iz = np.int64(np.floor(gz)) + 1
        # A neighbouring cell can hold a point within ri only if the point lies within ri of the
        # face they share (the same cell formula for both points, a relative margin for rounding):
        # a near point's radius (0.1 m) is a fraction of the cell, so most of the 26 are skipped.
        # Skipping cells whose points are all farther than ri cannot change the count's verdict.
        reach = ri / side * (1.0 + 1e-9) + 1e-9
        fx, fy, fz = gx - np.floor(gx), gy - np.floor(gy), gz - np.floor(gz)
        lo_x, hi_x = fx <= reach, 1.0 - fx <= reach
        lo_y, hi_y = fy <= reach, 1.0 - fy <= reach
        lo_z, hi_z = fz <= reach, 1.0 - fz <= reach
        count = 0  # the point itself is counted too (distance 0), so k others make k + 1
        # The point's own cell first, then the rest of its column and the 8 columns around it,
        # stopping at the (k + 1)-th point within radius: the answer does not depend on the order,
        # and on a dense surface (where most tested points pass) the own cell holds them. A point
        # never costs more than the points of its 27 cells.
        for o in range(9):
            ox = _RUN_ORDER_X[o]
            oy = _RUN_ORDER_Y[o]
            if (
                (ox < 0 and not lo_x)
                or (ox > 0 and not hi_x)
                or (oy < 0 and not lo_y)
                or (oy > 0 and not hi_y)
            ):
                continue
            c0 = ((ix + ox) * ny + iy + oy) * nz + iz - 1
            # The three cells along z, the point's own level first.
            for dz_cell in (1, 0, 2):
                if (dz_cell == 0 and not lo_z) or (dz_cell == 2 and not hi_z):
                    continue
                if bucketed:
                    q0, q1 = first[c0 + dz_cell], first[c0 + dz_cell + 1]
                else:
                    q0 = np.searchsorted(skey, c0 + dz_cell)
                    q1 = np.searchsorted(skey, c0 + dz_cell + 1)
                for q in range(q0, q1):
                    dx = xi - px[q]
                    dy = yi - py[q]
                    dz = zi - pz[q]
                    d2 = dx * dx + dy * dy + dz * dz
                    if d2 > out2:
                        continue
                    if d2 < in2 or (d2 < r_max2 and np.sqrt(d2) <= ri):
                        count += 1
                        if count > k:
                            break
                if count > k:
                    break
            if count > k:
                break
        out[t] = count > k
    return out


@njit(cache=True, nogil=True)
def scan_line_sure(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, key: np.ndarray, radius: np.ndarray, k: int
) -> np.ndarray:
    """(N,) bool: points with at least ``k`` of their ``k`` scan-line neighbours on each side within
    radius (the smaller radius of the two points), which DROR therefore keeps.

    Neighbours are taken in the given order within each scan line (``key``): a sweep lists a
    ring's returns in firing order, which is azimuth order, so they are the adjacent columns.
    Any order gives a sufficient test (the neighbours counted are real points within the radius);
    a shuffled cloud only leaves more points to :func:`enough_neighbours`.
    """
    n = x.shape[0]
    sure = np.zeros(n, np.bool_)
    if n == 0:
        return sure
    k_lo, k_hi = key.min(), key.max()
    span = k_hi - k_lo + 1
    # Each point's scan line as a small number: its key's offset when the key range is small
    # (rings of a few sensors), else the rank of its key among the distinct keys.
    if span <= 4 * n + _CELLS_SPARE:
        line = key - k_lo
        n_lines = span
    else:
        order = np.argsort(key, kind="mergesort")
        line = np.empty(n, np.int64)
        n_lines = 0
        for q in range(n):
            if q > 0 and key[order[q]] != key[order[q - 1]]:
                n_lines += 1
            line[order[q]] = n_lines
        n_lines += 1
    # One pass in the given order. The last k points met on each line are its k neighbours before
    # the current point in that line's own order: the pairs (and the arithmetic, later point minus
    # earlier) of the line-by-line passes, without grouping the lines first. Those points were
    # met a short while ago, so they are still in cache.
    last = np.full((n_lines, k), -1, np.int64)  # per line, the previous points, latest first
    count = np.zeros(n, np.int64)
    for b in range(n):
        prev = last[line[b]]
        for j in range(k):
            a = prev[j]
            if a < 0:
                break
            dx = x[b] - x[a]
            dy = y[b] - y[a]
            dz = z[b] - z[a]
            r = min(radius[a], radius[b])
            if dx * dx + dy * dy + dz * dz <= r * r:
                count[a] += 1
                count[b] += 1
        for j in range(k - 1, 0, -1):
            prev[j] = prev[j - 1]
        prev[0] = b
    for i in range(n):
        sure[i] = count[i] >= k
    return sure


@njit(cache=True, nogil=True)
def scan_window_counts(
    pool: np.ndarray,
    line: np.ndarray,
    ring: np.ndarray,
    azimuth: np.ndarray,
    rng: np.ndarray,
    z: np.ndarray,
    radius: np.ndarray,
    query: np.ndarray,
    ring_reach: int,
    tan_spacing: float,
    n_bins: int,
) -> np.ndarray:
    """(Q,) scan-pattern neighbours of each ``query`` point (the scan-pattern test of DROR).

    A candidate on scan line ``L`` has the key ``L * 10 + (azimuth + pi)``. For each of the
    ``2 ring_reach + 1`` lines around the query's, the pool points whose key lies in the query's
    azimuth window ``[L * 10 + lo, L * 10 + hi]`` (three windows: the +-pi seam; ``lo``, ``hi``
    its azimuth +- its angular width ``radius / range``, clipped to [0, 2 pi]) are tested for range
    (within the query's radius) and height (one ring spacing per ring apart, plus the radius).
    The pool is bucketed by line and by ``n_bins`` azimuth bins (a counting sort), so a window
    reads only the buckets it overlaps (with a margin far above the keys' rounding), and within
    them exactly the points whose key the window holds: the work per query is bounded by the
    points in its windows, whatever the rest of the cloud holds.

    Args:
        pool: (P,) int64 points that may count (every point within reach of a query's range).
        line, ring: (N,) int64 scan line (sensor-major, >= 0) and ring of every point.
        azimuth, rng, z, radius: (N,) float64 per point (rad in [-pi, pi], m, m, m).
        query: (Q,) int64 points to count for.
        ring_reach: rings either side searched.
        tan_spacing: tan of the ring spacing (height one ring apart may reach per metre of range).
        n_bins: azimuth bins per line (>= 1).
    """
    two_pi = 2.0 * np.pi
    out = np.zeros(query.shape[0], np.int64)
    m = pool.shape[0]
    if m == 0:
        return out
    n_lines = 0
    for t in range(m):
        n_lines = max(n_lines, line[pool[t]] + 1)
    scale = n_bins / two_pi
    bucket = np.empty(m, np.int64)
    first = np.zeros(n_lines * n_bins + 1, np.int64)
    for t in range(m):
        c = pool[t]
        b = min(max(np.int64(np.floor((azimuth[c] + np.pi) * scale)), 0), n_bins - 1)
        bucket[t] = line[c] * n_bins + b
        first[bucket[t] + 1] += 1
    for u in range(n_lines * n_bins):
        first[u + 1] += first[u]
    fill = first[:-1].copy()
    # The pool in bucket order, with what the window test reads copied beside it.
    skey = np.empty(m)
    sidx = np.empty(m, np.int64)
    for t in range(m):
        c = pool[t]
        q = fill[bucket[t]]
        fill[bucket[t]] += 1
        skey[q] = np.float64(line[c]) * 10.0 + (azimuth[c] + np.pi)
        sidx[q] = c
    margin = 1e-7  # rad: the keys are exact to ~1e-11 (line * 10 + angle, rounded once)
    for qi in range(query.shape[0]):
        me = query[qi]
        q_az = azimuth[me] + np.pi
        r_me, z_me, rad_me, ring_me = rng[me], z[me], radius[me], ring[me]
        q_w = rad_me / max(r_me, 1e-9)
        count = 0
        for dr in range(-ring_reach, ring_reach + 1):
            ln = line[me] + dr
            if ln < 0 or ln >= n_lines:
                continue  # no point lies on that line
            base = np.float64(ln) * 10.0
            for s in range(3):
                shift = (s - 1) * two_pi
                lo = min(max(q_az - q_w + shift, 0.0), two_pi)
                hi = min(max(q_az + q_w + shift, 0.0), two_pi)
                if not hi > lo:
                    continue
                k_lo, k_hi = base + lo, base + hi
                b0 = min(max(np.int64(np.floor((lo - margin) * scale)), 0), n_bins - 1)
                b1 = min(max(np.int64(np.floor((hi + margin) * scale)), 0), n_bins - 1)
                for t in range(first[ln * n_bins + b0], first[ln * n_bins + b1 + 1]):
                    if skey[t] < k_lo or skey[t] > k_hi:
                        continue
                    c = sidx[t]
                    if c == me or not abs(rng[c] - r_me) <= rad_me:
                        continue
                    tall = abs(ring[c] - ring_me) * r_me * tan_spacing + rad_me
                    if abs(z[c] - z_me) <= tall:
                        count += 1
        out[qi] = count
    return out


@njit(cache=True, nogil=True)
def first_of_each_value(values: np.ndarray) -> tuple[np.ndarray, bool]:
    """Indices of the first occurrence of each distinct value of ``values`` (float64, contiguous;
    -0.0 the same value as +0.0), in order of appearance, by open-addressing hashing of the bit
    patterns: one pass, whatever the order of the input. Also whether every value is finite
    (when one is not, the indices are empty: the caller sorts instead).

    A sweep's firing times take a few thousand distinct values (its columns) over ~10^5 points;
    sorting them all to find those values costs ~10x this pass. The table is sized for the
    distinct values met so far (grown fourfold, the firsts re-inserted in order, whenever it is
    half full), so it stays in cache instead of spanning twice the sweep; a value equal to the
    one before it (a column listed beam by beam) is no first and skips the table.
    """
    n = values.shape[0]
    first = np.empty(n, np.int64)
    if n == 0:
        return first, True
    bits = values.view(np.uint64)
    mult = np.uint64(0x9E3779B97F4A7C15)
    size = 4096
    shift = np.uint64(64 - 12)
    table = np.full(size, -1, np.int64)
    m = 0
    for i in range(n):
        v = values[i]
        if not np.isfinite(v):
            return first[:0], False
        if i > 0 and v == values[i - 1]:
            continue
        b = np.uint64(0) if v == 0.0 else bits[i]
        if 2 * m >= size:
            size *= 4
            shift -= np.uint64(2)
            table = np.full(size, -1, np.int64)
            for f in range(m):
                c = np.uint64(0) if values[first[f]] == 0.0 else bits[first[f]]
                h = np.int64((c * mult) >> shift)
                while table[h] >= 0:
                    h = (h + 1) & (size - 1)
                table[h] = first[f]
        h = np.int64((b * mult) >> shift)
        while True:
            j = table[h]
            if j < 0:
                table[h] = i
                first[m] = i
                m += 1
                break
            if values[j] == v:
                break
            h = (h + 1) & (size - 1)
    return first[:m], True


@njit(cache=True, nogil=True)
def dror_columns(
    xyz: np.ndarray,
    points: np.ndarray,
    rows: np.ndarray,
    unit_xy: np.ndarray,
    unit_step: np.ndarray,
    floor_step: float,
    multiplier: float,
    min_radius: float,
) -> tuple[
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
]:
    """DROR's per-point inputs for ``rows`` of a merged cloud, in one pass: x, y, z, the offsets
    dx, dy from the point's LiDAR, its range (libm ``hypot``, as ``np.hypot``), its radius
    ``max(min_radius, multiplier * range * max(step, floor_step))``, its scan key ``sensor * 1000 +
    ring``, its sensor and its ring (float32 columns truncated, as ``astype(np.int64)``).

    Args:
        xyz: (N, 3) float64 cloud coordinates.
        points: (N, >= 6) float32 cloud (ring in column 4, sensor index in column 5).
        rows: (M,) int64 rows to take.
        unit_xy: (S, 2) float64 each LiDAR's horizontal position; unit_step (S,) its column step.
    """
    m = rows.shape[0]
    x = np.empty(m)
    y = np.empty(m)
    z = np.empty(m)
    dx = np.empty(m)
    dy = np.empty(m)
    rng = np.empty(m)
    radius = np.empty(m)
    key = np.empty(m, np.int64)
    sensor = np.empty(m, np.int64)
    ring = np.empty(m, np.int64)
    n_units = unit_xy.shape[0]
    for q in range(m):
        i = rows[q]
        s = np.int64(points[i, 5])
        if s < 0 or s >= n_units:
            raise ValueError("dror_columns: a sensor index outside the units given")
        r = np.int64(points[i, 4])
        xi, yi = xyz[i, 0], xyz[i, 1]
        x[q], y[q], z[q] = xi, yi, xyz[i, 2]
        ox = xi - unit_xy[s, 0]
        oy = yi - unit_xy[s, 1]
        dx[q], dy[q] = ox, oy
        h = np.hypot(ox, oy)
        rng[q] = h
        step = unit_step[s] if unit_step[s] >= floor_step else floor_step
        a = multiplier * h * step
        radius[q] = a if a >= min_radius else min_radius
        key[q] = s * 1000 + r
        sensor[q] = s
        ring[q] = r
    return x, y, z, dx, dy, rng, radius, key, sensor, ring
