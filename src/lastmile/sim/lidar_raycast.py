"""Ray casting of a spinning LiDAR against vertical prisms (walls, cylinders, boxes).

A spinning LiDAR fires all its channels at (nearly) one azimuth at once: a *column*. Because every
solid here is a vertical prism, a column's rays share one line in the plane, so the work splits:

1. cull: each primitive's azimuth interval (seen from the sensor at the start and the end of the
   sweep, the primitive moved by its velocity) selects the columns that can see it, by a binary
   search in the columns' spin angle; only (column, primitive) pairs that can intersect exist;
2. per pair, one 2D intersection gives the horizontal entry and exit distances;
3. per pair, the channels whose ray meets the prism's side (or descends onto its top) form a
   contiguous interval of the elevation-sorted channels, found by another binary search;
4. the nearest hit per (column, channel) wins (as ``np.minimum.at`` over the flat cell index would
   pick it).

The per-primitive angles are NumPy; the loops over pairs and cells are compiled passes of
:mod:`lastmile.sim.lidar_kernel` (the same float operations in the same order as the NumPy
formulation they replaced: bit-identical sweeps). Cost scales with the number of (column, channel)
cells that actually meet something, not with rays x primitives.
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


def column_ranges(
    cols: Columns, pts_start: np.ndarray, pts_end: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (primitive, column) pairs whose azimuths can meet, as column ranges: (start, stop,
    primitive), each (R,); the pairs are every column in [start, stop) with its primitive, range after
    range.

    Args:
        cols: the sweep's columns.
        pts_start, pts_end: (P, M, 2) points bounding each primitive's footprint at the first and the
            last column's time (map frame).
    """
    n_col = len(cols)
    if len(pts_start) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    rel = np.concatenate([pts_start - cols.origin[0], pts_end - cols.origin[-1]], axis=1)
    ang = np.arctan2(rel[..., 1], rel[..., 0])
    dist = np.hypot(rel[..., 0], rel[..., 1]).min(axis=1)
    travel = float(np.hypot(*(cols.origin[-1] - cols.origin[0])))
    pad = 3.0 * (cols.spin[-1] / max(n_col - 1, 1))  # three columns of slack for yaw and motion
    # Each primitive's azimuth interval from the first column, widened by the pad, as up to three
    # column ranges (it may wrap past the end of the spin); one compiled pass.
    return lidar_kernel.spin_ranges(
        np.ascontiguousarray(ang),
        dist,
        0.5 + 2.0 * travel,
        float(cols.theta0_rad),
        cols.sign > 0,
        float(pad),
        np.ascontiguousarray(cols.spin, dtype=np.float64),
    )


def segment_pairs(cols: Columns, seg: Segments) -> tuple[np.ndarray, ...]:
    """Pairs with a wall: (prim, col, r_in, r_out, cos_2d) for rays that cross the wall ahead (one
    compiled pass over the candidate pairs, :func:`lidar_kernel.wall_pairs`)."""
    pts = np.stack([seg.p0, seg.p1], axis=1)
    starts, stops, ids = column_ranges(cols, pts, pts)
    p0x, p0y = np.ascontiguousarray(seg.p0[:, 0]), np.ascontiguousarray(seg.p0[:, 1])
    ex_w, ey_w = seg.p1[:, 0] - p0x, seg.p1[:, 1] - p0y
    ox, oy, dx, dy = (np.ascontiguousarray(a, dtype=np.float64) for a in (*cols.origin.T, *cols.direction.T))
    prim, col, r, cos2d = lidar_kernel.wall_pairs(
        starts, stops, ids, ox, oy, dx, dy, p0x, p0y, ex_w, ey_w, np.hypot(ex_w, ey_w)
    )
    return prim, col, r, r, cos2d


def _column_arrays(cols: Columns) -> tuple[np.ndarray, ...]:
    """The columns' origin x, y, direction x, y and firing time, each a contiguous (C,) float64."""
    return tuple(
        np.ascontiguousarray(a, dtype=np.float64) for a in (*cols.origin.T, *cols.direction.T, cols.t_s)
    )


def _moving(centre: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray, ...]:
    """Centre x, y and velocity x, y of moving primitives, each a contiguous (N,) float64."""
    return tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (*centre.T, *velocity.T))


def cylinder_pairs(cols: Columns, cyl: Cylinders) -> tuple[np.ndarray, ...]:
    """Pairs with a cylinder (moving with its velocity): (prim, col, r_in, r_out, cos_2d), one
    compiled pass over the candidate pairs (:func:`lidar_kernel.cylinder_pairs`)."""
    r = cyl.radius_m[:, None, None]
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])[None] * r
    t0, t1 = cols.t_s[0], cols.t_s[-1]
    c0 = cyl.centre + cyl.velocity * t0
    c1 = cyl.centre + cyl.velocity * t1
    ranges = column_ranges(cols, c0[:, None, :] + corners, c1[:, None, :] + corners)
    radius = np.ascontiguousarray(cyl.radius_m, dtype=np.float64)
    return lidar_kernel.cylinder_pairs(
        *ranges, *_column_arrays(cols), *_moving(cyl.centre, cyl.velocity), radius
    )


def box_pairs(cols: Columns, box: Boxes) -> tuple[np.ndarray, ...]:
    """Pairs with an oriented box (slab test in the box frame): (prim, col, r_in, r_out, cos_2d), one
    compiled pass over the candidate pairs (:func:`lidar_kernel.box_pairs`)."""
    c, s = np.cos(box.yaw_rad), np.sin(box.yaw_rad)
    hl, hw = box.half_length_m, box.half_width_m
    local = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    lx = local[None, :, 0] * hl[:, None]
    ly = local[None, :, 1] * hw[:, None]
    corners = np.stack([c[:, None] * lx - s[:, None] * ly, s[:, None] * lx + c[:, None] * ly], axis=-1)
    t0, t1 = cols.t_s[0], cols.t_s[-1]
    ranges = column_ranges(
        cols,
        corners + (box.centre + box.velocity * t0)[:, None, :],
        corners + (box.centre + box.velocity * t1)[:, None, :],
    )
    f8 = _contiguous(np.float64)
    return lidar_kernel.box_pairs(
        *ranges, *_column_arrays(cols), *_moving(box.centre, box.velocity), f8(c), f8(s), f8(hl), f8(hw)
    )


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
