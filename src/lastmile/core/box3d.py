"""Upright 3D boxes: rotated-rectangle overlap in the ground plane times height overlap, vectorised.

Tracking (association cost) and evaluation (KITTI 3D MOT matching) both need the same 3D IoU, and
evaluation may not import tracking, so the geometry lives here.

A box is one row of :data:`BOX3D_COLUMNS` in a right-handed frame with z up (the map frame, or KITTI
camera boxes converted by :func:`boxes_from_kitti_camera`): centre, extent along the heading
(``length_m``), across it (``width_m``), vertical extent (``height_m``) and heading about z.

The intersection of two convex quadrilaterals is the convex polygon whose vertices are the corners of
each inside the other plus the crossings of their edges; the vertices are ordered by angle around their
mean and the shoelace formula gives the area. Points on an edge count as inside (with a tolerance), so
identical, touching and nested boxes come out right, and parallel edges are skipped rather than divided
by zero (the reference evaluator's Sutherland-Hodgman clip divides by zero on identical boxes).
"""

from __future__ import annotations

import numpy as np

from lastmile.core.errors import MessageError

BOX3D_COLUMNS = ("x_m", "y_m", "z_m", "length_m", "width_m", "height_m", "yaw_rad")
"""Columns of a box array, shape (N, 7); ``z_m`` is the box centre's height."""

_EPS = 1e-9


def check_boxes(boxes: np.ndarray, what: str) -> np.ndarray:
    """``boxes`` as float64 (N, 7), finite, with non-negative extents.

    Raises:
        MessageError: naming ``what`` on a wrong shape, NaN/inf or a negative extent.
    """
    arr = np.asarray(boxes, dtype=np.float64)
    if arr.size == 0:
        arr = arr.reshape(0, len(BOX3D_COLUMNS))
    if arr.ndim != 2 or arr.shape[1] != len(BOX3D_COLUMNS):
        raise MessageError(f"{what}: expected shape (N, {len(BOX3D_COLUMNS)}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise MessageError(f"{what}: expected finite values, got NaN or inf")
    if np.any(arr[:, 3:6] < 0.0):
        raise MessageError(f"{what}: expected non-negative length, width and height, got a negative one")
    return arr


def boxes_from_kitti_camera(hwl_xyz_ry: np.ndarray) -> np.ndarray:
    """Convert KITTI camera boxes ``(h, w, l, x, y, z, rot_y)`` (y down, y at the bottom) to z-up boxes.

    Ground frame: x forward (camera z), y left (-camera x), z up (-camera y). This is a proper rotation,
    so overlaps are unchanged; heading ``yaw = -rot_y - pi/2`` (``rot_y = -pi/2`` faces forward).
    """
    a = np.asarray(hwl_xyz_ry, dtype=np.float64).reshape(-1, 7)
    h, w, length, x, y, z, ry = (a[:, i] for i in range(7))
    out = np.empty((a.shape[0], 7))
    out[:, 0] = z
    out[:, 1] = -x
    out[:, 2] = -y + 0.5 * h
    out[:, 3] = length
    out[:, 4] = w
    out[:, 5] = h
    out[:, 6] = wrap_angle(-ry - 0.5 * np.pi)
    return out


def kitti_camera_from_boxes(boxes: np.ndarray) -> np.ndarray:
    """Inverse of :func:`boxes_from_kitti_camera`: rows ``(h, w, l, x, y, z, rot_y)``."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
    out = np.empty((b.shape[0], 7))
    out[:, 0] = b[:, 5]
    out[:, 1] = b[:, 4]
    out[:, 2] = b[:, 3]
    out[:, 3] = -b[:, 1]
    out[:, 4] = -(b[:, 2] - 0.5 * b[:, 5])
    out[:, 5] = b[:, 0]
    out[:, 6] = wrap_angle(-b[:, 6] - 0.5 * np.pi)
    return out


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return np.mod(np.asarray(a, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi


def bev_corners(boxes: np.ndarray) -> np.ndarray:
    """Ground-plane corners, (N, 4, 2), counter-clockwise."""
    c, s = np.cos(boxes[:, 6]), np.sin(boxes[:, 6])
    hl, hw = 0.5 * boxes[:, 3], 0.5 * boxes[:, 4]
    local = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])  # (4, 2)
    lx = local[None, :, 0] * hl[:, None]
    ly = local[None, :, 1] * hw[:, None]
    x = boxes[:, None, 0] + c[:, None] * lx - s[:, None] * ly
    y = boxes[:, None, 1] + s[:, None] * lx + c[:, None] * ly
    return np.stack([x, y], axis=-1)


def _inside(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(K, P) whether each of P points lies in (or on) the counter-clockwise quad of its row."""
    e0 = quads
    e1 = np.roll(quads, -1, axis=1)
    edge = e1 - e0  # (K, 4, 2)
    rel = points[:, :, None, :] - e0[:, None, :, :]  # (K, P, 4, 2)
    cross = edge[:, None, :, 0] * rel[..., 1] - edge[:, None, :, 1] * rel[..., 0]
    scale = np.maximum(np.abs(edge).sum(axis=-1), 1.0)[:, None, :]
    return np.all(cross >= -1e-7 * scale, axis=-1)


def bev_intersection_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Ground-plane intersection area of row-aligned box pairs ``a[k]``, ``b[k]``; shape (K,)."""
    k = a.shape[0]
    if k == 0:
        return np.zeros(0)
    ca, cb = bev_corners(a), bev_corners(b)
    # Edge crossings: every edge of a against every edge of b, (K, 4, 4).
    p, r = ca[:, :, None, :], (np.roll(ca, -1, axis=1) - ca)[:, :, None, :]
    q, s = cb[:, None, :, :], (np.roll(cb, -1, axis=1) - cb)[:, None, :, :]
    rxs = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    qp = q - p
    parallel = np.abs(rxs) < _EPS
    safe = np.where(parallel, 1.0, rxs)
    t = (qp[..., 0] * s[..., 1] - qp[..., 1] * s[..., 0]) / safe
    u = (qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0]) / safe
    hit = ~parallel & (t >= 0.0) & (t <= 1.0) & (u >= 0.0) & (u <= 1.0)
    cross_pts = (p + t[..., None] * r).reshape(k, 16, 2)
    pts = np.concatenate([ca, cb, cross_pts], axis=1)  # (K, 24, 2)
    valid = np.concatenate([_inside(ca, cb), _inside(cb, ca), hit.reshape(k, 16)], axis=1)
    n_valid = valid.sum(axis=1)
    centre = (pts * valid[..., None]).sum(axis=1) / np.maximum(n_valid, 1)[:, None]
    ang = np.arctan2(pts[..., 1] - centre[:, None, 1], pts[..., 0] - centre[:, None, 0])
    ang = np.where(valid, ang, np.inf)
    order = np.argsort(ang, axis=1)
    sorted_pts = np.take_along_axis(pts, order[..., None], axis=1)
    # Invalid points sort last; repeating the first valid point there closes the polygon with
    # zero-length edges, so the shoelace sum needs no ragged arrays.
    sorted_valid = np.take_along_axis(valid, order, axis=1)
    sorted_pts = np.where(sorted_valid[..., None], sorted_pts, sorted_pts[:, :1, :])
    nxt = np.roll(sorted_pts, -1, axis=1)
    area = 0.5 * np.abs(np.sum(sorted_pts[..., 0] * nxt[..., 1] - sorted_pts[..., 1] * nxt[..., 0], axis=1))
    return np.where(n_valid >= 3, area, 0.0)


def iou3d_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3D IoU of row-aligned box pairs; 0 where both volumes are zero. Shape (K,)."""
    inter_bev = bev_intersection_pairs(a, b)
    top = np.minimum(a[:, 2] + 0.5 * a[:, 5], b[:, 2] + 0.5 * b[:, 5])
    bottom = np.maximum(a[:, 2] - 0.5 * a[:, 5], b[:, 2] - 0.5 * b[:, 5])
    inter = inter_bev * np.maximum(top - bottom, 0.0)
    union = a[:, 3] * a[:, 4] * a[:, 5] + b[:, 3] * b[:, 4] * b[:, 5] - inter
    return np.where(union > _EPS, inter / np.maximum(union, _EPS), 0.0).clip(0.0, 1.0)


def iou3d_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3D IoU of every box of ``a`` (N, 7) with every box of ``b`` (M, 7); shape (N, M).

    Only pairs whose ground-plane circumscribed circles touch are computed; the rest are 0.
    """
    n, m = a.shape[0], b.shape[0]
    out = np.zeros((n, m))
    if n == 0 or m == 0:
        return out
    ra = 0.5 * np.hypot(a[:, 3], a[:, 4])
    rb = 0.5 * np.hypot(b[:, 3], b[:, 4])
    d2 = (a[:, None, 0] - b[None, :, 0]) ** 2 + (a[:, None, 1] - b[None, :, 1]) ** 2
    ii, jj = np.nonzero(d2 <= (ra[:, None] + rb[None, :]) ** 2 + 1e-9)
    if ii.size:
        out[ii, jj] = iou3d_pairs(a[ii], b[jj])
    return out
