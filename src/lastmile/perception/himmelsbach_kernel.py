"""Compiled Himmelsbach line walk (Numba): each segment's prototypes walked outward, one segment at a time.

The array version advanced all segments in lockstep, one Python step per bin (~200 steps of a dozen
array operations: ~20 ms per frame whatever the cloud). Segments are independent, so each is walked
here on its own with the same scalar arithmetic in the same order (no fastmath), and the lines,
their ground verdicts and each bin's line come out bit-identical.
"""

from __future__ import annotations

import numpy as np

from lastmile.perception.jit_cache import njit


@njit(cache=True, nogil=True)
def lowest_per_cell(cell: np.ndarray, z: np.ndarray, n_cells: int) -> np.ndarray:
    """(n_cells,) the lowest ``z`` of each cell (inf where empty): ``np.minimum.at`` in one pass."""
    out = np.full(n_cells, np.inf)
    for i in range(cell.shape[0]):
        if z[i] < out[cell[i]]:
            out[cell[i]] = z[i]
    return out


@njit(cache=True, nogil=True)
def _fit(c: float, a_r: float, a_z: float, a_rr: float, a_rz: float) -> tuple[float, float]:
    den = c * a_rr - a_r * a_r
    m = (c * a_rz - a_r * a_z) / den if den > 1e-12 else 0.0
    return m, (a_z - m * a_r) / max(c, 1.0)


@njit(cache=True, nogil=True)
def walk_lines(
    has: np.ndarray,
    pz: np.ndarray,
    proto_r: np.ndarray,
    max_slope: float,
    small_slope: float,
    max_intercept_m: float,
    max_rmse_m: float,
    max_step_m: float,
    max_gap_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Lines of every segment: (S, B + 1) slopes, intercepts and ground verdicts, (S, B) each bin's
    line (-1 without a prototype). ``has``/``pz``: (S, B) prototypes; ``proto_r``: (B,) bin centres."""
    S, B = has.shape
    line_m = np.zeros((S, B + 1))
    line_b = np.zeros((S, B + 1))
    valid = np.zeros((S, B + 1), np.bool_)
    bin_line = np.full((S, B), -1, np.int64)
    for s in range(S):
        cnt = sr = sz = srr = srz = szz = 0.0
        r_first = r_last = z_first = 0.0
        line_id = 0
        # The last ground line; the road under the vehicle (z = 0) before any.
        prev_m = prev_b = prev_end = 0.0
        for j in range(B + 1):
            closing = j == B
            if not closing:
                if not has[s, j]:
                    continue
                rj, zj = proto_r[j], pz[s, j]
                c2, r2, z2 = cnt + 1, sr + rj, sz + zj
                rr2, rz2, zz2 = srr + rj * rj, srz + rj * zj, szz + zj * zj
                m2, b2 = _fit(c2, r2, z2, rr2, rz2)
                sse = zz2 - 2 * m2 * rz2 - 2 * b2 * z2 + m2 * m2 * rr2 + 2 * m2 * b2 * r2 + c2 * b2 * b2
                rmse = np.sqrt(max(sse, 0.0) / c2)
                good = (abs(m2) <= max_slope) and (rmse <= max_rmse_m)
                good = good and ((abs(m2) > small_slope) or (abs(b2) <= max_intercept_m))
                good = good and (rj - r_last <= max_gap_m)
                accept = cnt == 0 or good
                if accept:
                    if cnt == 0:
                        r_first = rj
                        z_first = zj
                    r_last = rj
                    cnt += 1
                    sr += rj
                    sz += zj
                    srr += rj * rj
                    srz += rj * zj
                    szz += zj * zj
                    bin_line[s, j] = line_id
                    continue
            # Close the current line (a restart, or the end of the segment) and judge it.
            m, b = _fit(cnt, sr, sz, srr, srz)
            one = cnt == 1
            if one:  # a one-point line continues the previous ground line's slope through its point
                m = prev_m
                b = z_first - m * r_first
            flat_ok = (abs(m) > small_slope) or (abs(b) <= max_intercept_m) or one
            step = abs((m * r_first + b) - (prev_m * r_first + prev_b))
            allowed = max_step_m + max_slope * max(r_first - prev_end, 0.0)
            ok = (abs(m) <= max_slope) and flat_ok and (step <= allowed) and (cnt > 0)
            line_m[s, line_id] = m
            line_b[s, line_id] = b
            valid[s, line_id] = ok
            if ok:
                prev_m, prev_b, prev_end = m, b, r_last
            if closing:
                break
            line_id += 1
            cnt = 1.0
            sr, sz, srr, srz, szz = rj, zj, rj * rj, rj * zj, zj * zj
            r_first = r_last = rj
            z_first = zj
            bin_line[s, j] = line_id
    return line_m, line_b, valid, bin_line


@njit(cache=True, nogil=True)
def point_cells(
    r: np.ndarray, az: np.ndarray, n_segments: int, n_bins: int, bin_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(N,) segment ``floor((az + pi) / 2 pi * S) mod S`` and bin ``min(floor(r / bin_m), B - 1)``
    of every point (the array expressions' arithmetic)."""
    n = r.shape[0]
    seg = np.empty(n, np.int64)
    b = np.empty(n, np.int64)
    for i in range(n):
        k = np.int64(np.floor((az[i] + np.pi) / (2 * np.pi) * n_segments))
        # Python's modulo only where needed (az = pi or outside +-pi): the integer division is slow.
        seg[i] = k if 0 <= k < n_segments else k % n_segments
        b[i] = min(int(r[i] / bin_m), n_bins - 1)  # truncation, as astype(int64)
    return seg, b


@njit(cache=True, nogil=True)
def label_points(
    seg: np.ndarray,
    b: np.ndarray,
    r: np.ndarray,
    z: np.ndarray,
    filled: np.ndarray,
    line_m: np.ndarray,
    line_b: np.ndarray,
    valid: np.ndarray,
    ground_distance_m: float,
) -> np.ndarray:
    """(N,) ground: the point's bin has a ground line and the point lies at most
    ``ground_distance_m`` above it."""
    out = np.zeros(seg.shape[0], np.bool_)
    for i in range(seg.shape[0]):
        line = filled[seg[i], b[i]]
        k = max(line, 0)
        height = z[i] - (line_m[seg[i], k] * r[i] + line_b[seg[i], k])
        if line >= 0 and valid[seg[i], k] and height <= ground_distance_m:
            out[i] = True
    return out


@njit(cache=True, nogil=True)
def fill_forward(ids: np.ndarray) -> np.ndarray:
    """(S, B) ``ids`` with each -1 replaced by the last non-negative entry to its left in its row,
    or, before the row's first non-negative entry, by that entry (rows without one stay -1)."""
    n_seg, n_bins = ids.shape
    out = np.empty_like(ids)
    for s in range(n_seg):
        lead = -1
        for b in range(n_bins):
            if ids[s, b] >= 0:
                lead = ids[s, b]
                break
        last = lead
        for b in range(n_bins):
            if ids[s, b] >= 0:
                last = ids[s, b]
            out[s, b] = last
    return out


@njit(cache=True, nogil=True)
def segment_members(az: np.ndarray, points: np.ndarray, n_segments: int) -> np.ndarray:
    """Ascending indices of every point whose segment (:func:`point_cells`'s formula on ``az``)
    holds one of ``points``."""
    need = np.zeros(n_segments, np.bool_)
    for q in range(points.shape[0]):
        need[_segment(az[points[q]], n_segments)] = True
    members = np.empty(az.shape[0], np.int64)
    m = 0
    for i in range(az.shape[0]):
        if need[_segment(az[i], n_segments)]:
            members[m] = i
            m += 1
    return members[:m].copy()


@njit(cache=True, nogil=True, inline="always")
def _segment(az: float, n_segments: int) -> np.int64:
    k = np.int64(np.floor((az + np.pi) / (2 * np.pi) * n_segments))
    # Python's modulo only where needed (az = pi or outside +-pi): the integer division is slow.
    return k if 0 <= k < n_segments else k % n_segments
