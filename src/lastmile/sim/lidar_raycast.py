"""Vectorised ray casting of a spinning LiDAR against vertical prisms (walls, cylinders, boxes).

A spinning LiDAR fires all its channels at (nearly) one azimuth at once: a *column*. Because every
solid here is a vertical prism, a column's rays share one line in the plane, so the work splits:

1. cull: each primitive's azimuth interval (seen from the sensor at the start and the end of the
   sweep, the primitive moved by its velocity) selects the columns that can see it, by a binary
   search in the columns' spin angle; only (column, primitive) pairs that can intersect exist;
2. per pair, one 2D intersection gives the horizontal entry and exit distances;
3. per pair, the channels whose ray meets the prism's side (or descends onto its top) form a
   contiguous interval of the elevation-sorted channels, found by another binary search;
4. the nearest hit per (column, channel) wins (as ``np.minimum.at`` over the flat cell index would
   pick it; steps 3's expansion and 4 are one compiled pass, :func:`lidar_kernel.nearest_hits`).

All arrays are NumPy; cost scales with the number of (column, channel) cells that actually meet
something, not with rays x primitives.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lastmile.sim import lidar_kernel
from lastmile.sim.lidar_scene import Boxes, Cylinders, Segments

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True, kw_only=True)
class Columns:
    """The firing columns of one sweep, in the map frame.

    Attributes:
        origin: (C, 2) float64 sensor position when the column fires (m).
        direction: (C, 2) float64 unit horizontal direction of the column.
        t_s: (C,) float64 firing time relative to the objects' reference time (s).
        spin: (C,) float64 non-decreasing spin angle from the first column (rad).
        theta0_rad: map-frame direction of the first column; sign: +1 counter-clockwise spin, -1 clockwise.
        z_m: sensor height above the road (m).
    """

    origin: np.ndarray
    direction: np.ndarray
    t_s: np.ndarray
    spin: np.ndarray
    theta0_rad: float
    sign: float
    z_m: float

    def __len__(self) -> int:
        return len(self.origin)


@dataclass(frozen=True, slots=True, kw_only=True)
class Hits:
    """Nearest prism hit per (column, channel); channels in ascending elevation.

    Attributes:
        range_h_m: (C, K) float64 horizontal distance to the hit (inf: no prism hit).
        prim: (C, K) int64 index into the concatenated primitive table (-1: none).
        cos_incidence: (C, K) float64 cosine between the ray and the surface normal.
    """

    range_h_m: np.ndarray
    prim: np.ndarray
    cos_incidence: np.ndarray


def _expand(starts: np.ndarray, stops: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(id, position) for every position in [start, stop) of every id."""
    counts = np.maximum(stops - starts, 0)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    rep_ids = np.repeat(ids, counts)
    offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return rep_ids, np.repeat(starts, counts) + offsets


def column_pairs(cols: Columns, pts_start: np.ndarray, pts_end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(primitive, column) pairs whose azimuths can meet.

    Args:
        cols: the sweep's columns.
        pts_start, pts_end: (P, M, 2) points bounding each primitive's footprint at the first and the
            last column's time (map frame).
    """
    n_col = len(cols)
    if len(pts_start) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    rel = np.concatenate([pts_start - cols.origin[0], pts_end - cols.origin[-1]], axis=1)
    ang = np.arctan2(rel[..., 1], rel[..., 0])
    ref = ang[:, 0]
    d = (ang - ref[:, None] + math.pi) % TWO_PI - math.pi
    lo, hi = ref + d.min(axis=1), ref + d.max(axis=1)
    travel = float(np.hypot(*(cols.origin[-1] - cols.origin[0])))
    near = (np.hypot(rel[..., 0], rel[..., 1]).min(axis=1) < 0.5 + 2.0 * travel) | (hi - lo > 0.9 * math.pi)
    if cols.sign > 0:
        a, b = lo - cols.theta0_rad, hi - cols.theta0_rad
    else:
        a, b = cols.theta0_rad - hi, cols.theta0_rad - lo
    pad = 3.0 * (cols.spin[-1] / max(n_col - 1, 1))  # three columns of slack for yaw and motion
    a, b = a - pad, b + pad
    shift = np.floor(a / TWO_PI) * TWO_PI
    a, b = a - shift, b - shift
    ids = np.arange(len(pts_start))
    starts, stops = [], []
    for k in (-1.0, 0.0, 1.0):
        s = np.searchsorted(cols.spin, a + k * TWO_PI, side="left")
        e = np.searchsorted(cols.spin, b + k * TWO_PI, side="right")
        if k == 0.0:
            s, e = np.where(near, 0, s), np.where(near, n_col, e)
        else:
            e = np.where(near, s, e)
        starts.append(s)
        stops.append(e)
    return _expand(np.concatenate(starts), np.concatenate(stops), np.tile(ids, 3))


def _column_parts(cols: Columns, col: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Origin x, y and direction x, y of the columns ``col``, each gathered as a 1-D array (a take
    from a contiguous column is several times cheaper than a gather of (C, 2) rows)."""
    return (
        np.ascontiguousarray(cols.origin[:, 0]).take(col),
        np.ascontiguousarray(cols.origin[:, 1]).take(col),
        np.ascontiguousarray(cols.direction[:, 0]).take(col),
        np.ascontiguousarray(cols.direction[:, 1]).take(col),
    )


def _cross(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    return ax * by - ay * bx


def segment_pairs(cols: Columns, seg: Segments) -> tuple[np.ndarray, ...]:
    """Pairs with a wall: (prim, col, r_in, r_out, cos_2d) for rays that cross the wall ahead."""
    pts = np.stack([seg.p0, seg.p1], axis=1)
    prim, col = column_pairs(cols, pts, pts)
    ox, oy, dx, dy = _column_parts(cols, col)
    # Per wall once, then gathered per pair (1-D takes): the same values as per-pair arithmetic.
    p0x, p0y = np.ascontiguousarray(seg.p0[:, 0]), np.ascontiguousarray(seg.p0[:, 1])
    ex_w, ey_w = seg.p1[:, 0] - p0x, seg.p1[:, 1] - p0y
    ex, ey = ex_w.take(prim), ey_w.take(prim)
    wx, wy = p0x.take(prim) - ox, p0y.take(prim) - oy
    denom = _cross(dx, dy, ex, ey)
    ok = np.abs(denom) > 1e-12
    safe = np.where(ok, denom, 1.0)
    r = _cross(wx, wy, ex, ey) / safe
    u = _cross(wx, wy, dx, dy) / safe
    ok &= (u >= 0.0) & (u <= 1.0) & (r > 0.0)
    keep = np.flatnonzero(ok)
    cos2d = np.abs(denom.take(keep)) / np.hypot(ex_w, ey_w).take(prim.take(keep))
    r_k = r.take(keep)
    return prim.take(keep), col.take(keep), r_k, r_k, cos2d


def cylinder_pairs(cols: Columns, cyl: Cylinders) -> tuple[np.ndarray, ...]:
    """Pairs with a cylinder (moving with its velocity): (prim, col, r_in, r_out, cos_2d)."""
    r = cyl.radius_m[:, None, None]
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])[None] * r
    t0, t1 = cols.t_s[0], cols.t_s[-1]
    c0 = cyl.centre + cyl.velocity * t0
    c1 = cyl.centre + cyl.velocity * t1
    prim, col = column_pairs(cols, c0[:, None, :] + corners, c1[:, None, :] + corners)
    t_s = cols.t_s.take(col)
    cx = (
        np.ascontiguousarray(cyl.centre[:, 0]).take(prim)
        + np.ascontiguousarray(cyl.velocity[:, 0]).take(prim) * t_s
    )
    cy = (
        np.ascontiguousarray(cyl.centre[:, 1]).take(prim)
        + np.ascontiguousarray(cyl.velocity[:, 1]).take(prim) * t_s
    )
    ox, oy, dx, dy = _column_parts(cols, col)
    rx, ry = ox - cx, oy - cy
    b = rx * dx + ry * dy
    rad = cyl.radius_m.take(prim)
    disc = b * b - (rx * rx + ry * ry - rad * rad)
    ok = disc >= 0.0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    r_in, r_out = -b - sq, -b + sq
    ok &= r_out > 0.0
    cos2d = sq / rad
    return prim[ok], col[ok], r_in[ok], r_out[ok], cos2d[ok]


def box_pairs(cols: Columns, box: Boxes) -> tuple[np.ndarray, ...]:
    """Pairs with an oriented box (slab test in the box frame): (prim, col, r_in, r_out, cos_2d)."""
    c, s = np.cos(box.yaw_rad), np.sin(box.yaw_rad)
    hl, hw = box.half_length_m, box.half_width_m
    local = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    lx = local[None, :, 0] * hl[:, None]
    ly = local[None, :, 1] * hw[:, None]
    corners = np.stack([c[:, None] * lx - s[:, None] * ly, s[:, None] * lx + c[:, None] * ly], axis=-1)
    t0, t1 = cols.t_s[0], cols.t_s[-1]
    prim, col = column_pairs(
        cols,
        corners + (box.centre + box.velocity * t0)[:, None, :],
        corners + (box.centre + box.velocity * t1)[:, None, :],
    )
    t_s = cols.t_s.take(col)
    cx = (
        np.ascontiguousarray(box.centre[:, 0]).take(prim)
        + np.ascontiguousarray(box.velocity[:, 0]).take(prim) * t_s
    )
    cy = (
        np.ascontiguousarray(box.centre[:, 1]).take(prim)
        + np.ascontiguousarray(box.velocity[:, 1]).take(prim) * t_s
    )
    px, py, dx, dy = _column_parts(cols, col)
    cp, sp = c.take(prim), s.take(prim)
    ox, oy = px - cx, py - cy
    lox, loy = cp * ox + sp * oy, -sp * ox + cp * oy
    ldx, ldy = cp * dx + sp * dy, -sp * dx + cp * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        tx1, tx2 = (-hl[prim] - lox) / ldx, (hl[prim] - lox) / ldx
        ty1, ty2 = (-hw[prim] - loy) / ldy, (hw[prim] - loy) / ldy
    # A ray parallel to a slab is inside it (both bounds infinite) or outside (never enters).
    in_x = np.abs(lox) <= hl[prim]
    in_y = np.abs(loy) <= hw[prim]
    tx_lo = np.where(ldx == 0.0, np.where(in_x, -np.inf, np.inf), np.minimum(tx1, tx2))
    tx_hi = np.where(ldx == 0.0, np.where(in_x, np.inf, -np.inf), np.maximum(tx1, tx2))
    ty_lo = np.where(ldy == 0.0, np.where(in_y, -np.inf, np.inf), np.minimum(ty1, ty2))
    ty_hi = np.where(ldy == 0.0, np.where(in_y, np.inf, -np.inf), np.maximum(ty1, ty2))
    r_in = np.maximum(tx_lo, ty_lo)
    r_out = np.minimum(tx_hi, ty_hi)
    ok = (r_out >= r_in) & (r_out > 0.0)
    cos2d = np.where(tx_lo > ty_lo, np.abs(ldx), np.abs(ldy))
    return prim[ok], col[ok], r_in[ok], r_out[ok], cos2d[ok]


def _contiguous(dtype: type) -> Callable[[np.ndarray], np.ndarray]:
    """A converter to a C-contiguous array of ``dtype`` (the array itself when it already is one)."""
    return lambda a: np.ascontiguousarray(a, dtype=dtype)


def cast(
    cols: Columns,
    tan_el: np.ndarray,
    prim_z: tuple[np.ndarray, np.ndarray],
    pairs: tuple[np.ndarray, ...],
    max_range_h_m: float,
) -> Hits:
    """Nearest prism hit of every (column, channel) ray.

    Args:
        cols: the sweep's columns.
        tan_el: (K,) ascending tangents of the channels' elevations.
        prim_z: (z_min, z_max) of every primitive in the concatenated table, (P,) each.
        pairs: concatenated (prim, col, r_in, r_out, cos_2d) from the ``*_pairs`` functions, with prim
            already offset into the concatenated table.
        max_range_h_m: pairs entering beyond this horizontal distance are skipped.
    """
    n_col, n_ch = len(cols), len(tan_el)
    prim, col, r_in, r_out, cos2d = pairs
    keep = r_in < max_range_h_m
    prim, col, r_in, r_out, cos2d = prim[keep], col[keep], r_in[keep], r_out[keep], cos2d[keep]
    # A sensor inside a prism (or touching it) is blocked at once: a zero-range hit the caller drops.
    r_in = np.maximum(r_in, 1e-6)
    oz = cols.z_m
    z_lo, z_hi = prim_z[0][prim], prim_z[1][prim]
    tan_lo = (z_lo - oz) / r_in
    tan_hi = np.where(z_hi >= oz, (z_hi - oz) / r_in, (z_hi - oz) / r_out)
    k0 = np.searchsorted(tan_el, tan_lo, side="left")
    k1 = np.searchsorted(tan_el, tan_hi, side="right")
    # Steps 3 and 4 in one compiled pass over the (pair, channel) cells, without expanding them
    # (one dtype per argument: the compiled signature the warm-up caches).
    f8, i8 = _contiguous(np.float64), _contiguous(np.int64)
    best, prim_out, cos_out = lidar_kernel.nearest_hits(
        n_col, n_ch, f8(tan_el), float(oz), i8(col), i8(k0), i8(k1), f8(r_in), f8(z_hi), f8(cos2d), i8(prim)
    )
    return Hits(
        range_h_m=best.reshape(n_col, n_ch),
        prim=prim_out.reshape(n_col, n_ch),
        cos_incidence=cos_out.reshape(n_col, n_ch),
    )
