"""Cubic Bezier curves: pull-over and merge transitions, and smoothing through waypoints."""

from __future__ import annotations

import numpy as np

from lastmile.core.geometry import FloatArray


def cubic_bezier(p0: FloatArray, p1: FloatArray, p2: FloatArray, p3: FloatArray, count: int) -> FloatArray:
    """(count, D) points of the cubic Bezier with control points p0..p3 (each (D,))."""
    t = np.linspace(0.0, 1.0, count)[:, None]
    u = 1.0 - t
    return u**3 * p0 + 3 * u**2 * t * p1 + 3 * u * t**2 * p2 + t**3 * p3


def lateral_transition_m(s_m: FloatArray, s0_m: float, s1_m: float, d0_m: float, d1_m: float) -> FloatArray:
    """Offset d(s) moving from d0 (before s0) to d1 (after s1) along a cubic Bezier in the (s, d) plane.

    Control points sit level with the ends (tangent to the lane and to the target line), so the path
    leaves and joins both with zero heading difference and bounded curvature, as WATonoBus's pull-over
    and merge curves do.
    """
    s = np.asarray(s_m, dtype=float)
    out = np.where(s <= s0_m, d0_m, d1_m).astype(float)
    if s1_m <= s0_m:
        return out
    mid = (s > s0_m) & (s < s1_m)
    if np.any(mid):
        third = (s1_m - s0_m) / 3.0
        curve = cubic_bezier(
            np.array([s0_m, d0_m]),
            np.array([s0_m + third, d0_m]),
            np.array([s1_m - third, d1_m]),
            np.array([s1_m, d1_m]),
            64,
        )
        out[mid] = np.interp(s[mid], curve[:, 0], curve[:, 1])
    return out


def smooth_through(points: FloatArray, samples_per_segment: int = 8) -> FloatArray:
    """A C1 chain of cubic Beziers through (N, 2) waypoints (Catmull-Rom tangents), as (M, 2) points."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 3:
        return pts.copy()
    padded = np.vstack([2 * pts[0] - pts[1], pts, 2 * pts[-1] - pts[-2]])
    # All segments at once, (S, 1, 2) control points against (1, K, 1) parameters: the same
    # arithmetic as one cubic_bezier call per segment, without a Python loop per planning cycle.
    p0, p3 = padded[1:-2, None, :], padded[2:-1, None, :]
    p1 = p0 + (padded[2:-1, None, :] - padded[:-3, None, :]) / 6.0
    p2 = p3 - (padded[3:, None, :] - padded[1:-2, None, :]) / 6.0
    t = np.linspace(0.0, 1.0, samples_per_segment + 1)[None, :, None]
    u = 1.0 - t
    segs = u**3 * p0 + 3 * u**2 * t * p1 + 3 * u * t**2 * p2 + t**3 * p3
    return np.vstack([segs[:, :-1, :].reshape(-1, 2), segs[-1, -1:, :]])
