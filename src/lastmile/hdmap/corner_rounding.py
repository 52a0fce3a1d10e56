"""Corners of a mapped centre line that the shuttle cannot steer, rounded within the road.

A lanelet's centre line is what a mapper clicked: on real maps it can turn 35-80 degrees at a single
vertex (the BITS campus loop's S-bend near K-Block). Followed as drawn, such a corner asks for
curvature no vehicle has: the controller saturates its steering, the shuttle crawls, and a pull-over
laid along it (a stop just after the corner) cannot be driven, so the door never reaches the curb.
Here every stretch whose turning over a wheelbase exceeds the curvature a lane change may use
(``lane_change.STEER_SHARE`` of the vehicle's tightest) becomes a circular fillet of exactly that
curvature, tangent to the straight runs either side (taken further out until the fillet fits
between them, as far as the line goes), as a road designer rounds a corner; the fillet is checked
with the shuttle's half-width on both sides against the drivable lanelets and kept only if it is no
more off the road than the line as mapped. Corners between two runs that are not straight (an S
drawn without a straight between its bends) are left as drawn. Lines without such corners (the
built-in campus loop) are returned as they are, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.lane_change import STEER_SHARE, RoadOutline
from lastmile.hdmap.model import HDMap

SAMPLE_M = 0.25
"""Vertex spacing inside a rounded stretch (the same as inside a lane change)."""
MERGE_GAP_M = 1.0
"""Sharp vertices closer than this along the line are one corner."""
EXTEND_STEP_M = 0.5
"""How far the straight run either side of a corner grows per try, until the arc fits between them."""


def max_curvature_per_m(geometry: VehicleGeometry) -> float:
    """The curvature the route may ask for: STEER_SHARE of the vehicle's tightest."""
    return STEER_SHARE * math.tan(geometry.max_steer_rad) / geometry.wheelbase_m


def round_corners(
    hdmap: HDMap, xy: np.ndarray, closed: bool, geometry: VehicleGeometry | None = None
) -> np.ndarray:
    """The centre line ``xy`` ((N, 2); closed lines without a repeated first vertex) with every corner
    sharper than the vehicle can steer replaced by a circular fillet of the steerable radius, tangent
    to the straight runs either side, where the road allows."""
    geometry = geometry or VehicleGeometry()
    kappa_max = max_curvature_per_m(geometry)
    window = geometry.wheelbase_m
    # Sharpness is measured on the densified line: a window centred on every mapped vertex alone
    # would miss a bend drawn as several moderate vertices closer together than the window.
    dense, arc = _densify(xy, closed)
    stretches = _sharp_stretches(dense[:-1] if closed else dense, closed, window, kappa_max)
    if not stretches:
        return xy
    road = RoadOutline(hdmap)
    out, changed = dense, False
    # Last corner first: splicing one changes the arc lengths after it, not before.
    for lo, hi in sorted(stretches, reverse=True):
        piece = _fillet(out, arc, lo, hi, 1.0 / kappa_max, window)
        if piece is None:
            continue
        a, b, pts = piece
        inside = (arc > a) & (arc < b)
        before = _off_road(road, out[inside], geometry)
        if _off_road(road, pts, geometry) > before:
            continue  # never trade the mapped line for one further off the road
        keep_lo, keep_hi = np.flatnonzero(arc <= a), np.flatnonzero(arc >= b)
        new_pts = np.vstack([out[keep_lo], pts, out[keep_hi]])
        seg = np.hypot(*np.diff(new_pts, axis=0).T)
        out, arc, changed = new_pts, np.concatenate([[0.0], np.cumsum(seg)]), True
    if not changed:
        return xy
    return out[:-1] if closed else out


def _fillet(
    xy: np.ndarray, arc: np.ndarray, lo: float, hi: float, radius_m: float, run_m: float
) -> tuple[float, float, np.ndarray] | None:
    """(a, b, points strictly between): the line from arc a to b replaced by straight, arc of
    ``radius_m``, straight, tangent to the runs of ``run_m`` before a and after b. None when the
    corner crosses the line's ends or no fillet fits before them.

    The runs grow until the fillet fits, with no length limit of their own: a bend drawn as several
    kinks needs its tangents far out (26.5 m on the BITS loop), and what keeps a long fillet honest
    is the road check its caller makes (never more off the drivable lanelets than the mapped line).
    """
    total = float(arc[-1])
    ext = 0.0
    while True:
        a, b = lo - ext, hi + ext
        ext += EXTEND_STEP_M
        if a - run_m < 0.0 or b + run_m > total:
            return None
        pa, pb = _at(xy, arc, a), _at(xy, arc, b)
        u_in = pa - _at(xy, arc, a - run_m)
        u_out = _at(xy, arc, b + run_m) - pb
        u_in, u_out = u_in / np.hypot(*u_in), u_out / np.hypot(*u_out)
        # The runs the fillet is tangent to must themselves be steerable (a gentle curve is fine).
        bend = run_m / radius_m
        if not (_straight(xy, arc, a - run_m, a, bend) and _straight(xy, arc, b, b + run_m, bend)):
            continue
        cross = u_in[0] * u_out[1] - u_in[1] * u_out[0]
        turn = math.atan2(cross, float(u_in @ u_out))
        if abs(cross) < 1e-6:
            return None  # parallel runs (an S-bend, a wobble): no single fillet
        # V = pa + t u_in = pb - r u_out
        rhs = pb - pa
        t = (rhs[0] * u_out[1] - rhs[1] * u_out[0]) / cross
        r = (u_in[0] * rhs[1] - u_in[1] * rhs[0]) / cross
        tangent = radius_m * math.tan(abs(turn) / 2.0)
        if t < tangent or r < tangent:
            continue
        v = pa + t * u_in
        p1, p2 = v - tangent * u_in, v + tangent * u_out
        normal = np.array([-u_in[1], u_in[0]]) * math.copysign(1.0, turn)
        centre = p1 + radius_m * normal
        phi0 = math.atan2(p1[1] - centre[1], p1[0] - centre[0])
        n = max(2, math.ceil(abs(turn) * radius_m / SAMPLE_M) + 1)
        phi = phi0 + np.linspace(0.0, turn, n)
        curve = centre + radius_m * np.c_[np.cos(phi), np.sin(phi)]
        lead = _line(pa, p1)
        tail = _line(p2, pb)
        return (
            a,
            b,
            np.vstack([lead[1:], curve[1:-1], tail[:-1]])
            if len(tail) > 1
            else np.vstack([lead[1:], curve[1:-1]]),
        )


def _line(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Points from p to q (both included) every SAMPLE_M at most."""
    n = max(2, math.ceil(float(np.hypot(*(q - p))) / SAMPLE_M) + 1)
    return p + np.linspace(0.0, 1.0, n)[:, None] * (q - p)


def _at(xy: np.ndarray, arc: np.ndarray, s: float) -> np.ndarray:
    return np.array([np.interp(s, arc, xy[:, 0]), np.interp(s, arc, xy[:, 1])])


def _straight(xy: np.ndarray, arc: np.ndarray, s0: float, s1: float, tolerance_rad: float) -> bool:
    """The line turns by at most ``tolerance_rad`` between any two of its vertices in [s0, s1]."""
    inside = (arc >= s0) & (arc <= s1)
    pts = np.vstack([_at(xy, arc, s0), xy[inside], _at(xy, arc, s1)])
    seg = np.diff(pts, axis=0)
    seg = seg[np.hypot(seg[:, 0], seg[:, 1]) > 1e-9]
    heading = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    return bool(np.ptp(heading) <= tolerance_rad) if len(heading) else False


def _sharp_stretches(
    xy: np.ndarray, closed: bool, window_m: float, kappa_max: float
) -> list[tuple[float, float]]:
    """(start, end) arc of each stretch whose turning over ``window_m`` exceeds kappa_max * window_m."""
    arc, turn = _turning(xy, closed)
    total = float(arc[-1]) if closed else math.inf
    summed = _window_sum(arc[:-1] if closed else arc, turn, window_m, total)
    sharp = np.flatnonzero(np.abs(summed) > kappa_max * window_m)
    out: list[tuple[float, float]] = []
    for k in sharp.tolist():
        s = float(arc[k])
        if out and s - out[-1][1] <= MERGE_GAP_M:
            out[-1] = (out[-1][0], s)
        else:
            out.append((s, s))
    # The stretch spans the corners' window either side; stretches that then touch are one bend (a
    # curve drawn as several sharp vertices is rounded as a whole).
    merged: list[tuple[float, float]] = []
    for lo, hi in out:
        lo, hi = lo - window_m / 2.0, hi + window_m / 2.0
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], hi)
        else:
            merged.append((lo, hi))
    return merged


def _turning(xy: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Arc length at each vertex (closed: the first repeated at the end) and the heading change there
    (0 at an open line's ends)."""
    pts = np.vstack([xy, xy[:1]]) if closed else xy
    seg = np.diff(pts, axis=0)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    if closed:
        turn = _wrap(heading - np.roll(heading, 1))  # at vertex k: into segment k from segment k - 1
    else:
        turn = np.concatenate([[0.0], _wrap(np.diff(heading)), [0.0]])
    return arc, turn


def _window_sum(arc: np.ndarray, values: np.ndarray, window_m: float, total: float) -> np.ndarray:
    """Sum of ``values`` at the vertices within window_m / 2 of each vertex (wrapping a loop of
    length ``total``)."""
    if math.isfinite(total):
        arc3 = np.concatenate([arc - total, arc, arc + total])
        val3 = np.concatenate([values, values, values])
    else:
        arc3, val3 = arc, values
    cum = np.concatenate([[0.0], np.cumsum(val3)])
    hi = np.searchsorted(arc3, arc + window_m / 2.0, side="right")
    lo = np.searchsorted(arc3, arc - window_m / 2.0, side="left")
    return cum[hi] - cum[lo]


def _off_road(road: RoadOutline, xy: np.ndarray, g: VehicleGeometry) -> int:
    """How many vertices of the piece ``xy`` put the shuttle's side (half its width out) off the
    drivable lanelets."""
    if len(xy) < 2:
        return 0
    tangent = np.gradient(xy, axis=0)
    norm = np.hypot(tangent[:, 0], tangent[:, 1])
    ok = norm > 1e-9
    tangent = tangent[ok] / norm[ok, None]
    normal = np.c_[-tangent[:, 1], tangent[:, 0]]
    half = g.width_m / 2.0
    pts = np.vstack([xy[ok] + half * normal, xy[ok] - half * normal])
    return int((~road.contains(pts)).sum())


def _densify(xy: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Vertices every SAMPLE_M (the mapped ones kept) and their arc length; a closed line repeats its
    first vertex at the end."""
    pts = np.vstack([xy, xy[:1]]) if closed else xy
    seg = np.hypot(*np.diff(pts, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    grid = np.arange(0.0, s[-1], SAMPLE_M)
    idx = np.clip(np.searchsorted(s, grid), 1, len(s) - 1)
    nearest = np.minimum(np.abs(grid - s[idx - 1]), np.abs(grid - s[idx]))
    fine = np.unique(np.concatenate([s, grid[nearest > SAMPLE_M / 4]]))
    dense = np.c_[np.interp(fine, s, pts[:, 0]), np.interp(fine, s, pts[:, 1])]
    return dense, fine


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi
