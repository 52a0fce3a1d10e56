"""Lane changes a shuttle can drive: a smooth lateral shift, long enough for comfort, across lanelets.

``route_pieces`` leaves one lanelet and joins the one beside it; the joined centre line then jumps
sideways by a lane width. Here each jump becomes a quintic lateral transition (zero slope and
curvature at both ends, so the path's curvature stays continuous), whose length keeps its own peak
lateral acceleration at the lane's speed limit within the comfort bound (the same 1.0 m/s² as the
speed profile's curvature limit) and never below what the vehicle's steering can follow. The
transition may span several lanelets (a roundabout's are 5-10 m long) and several lane changes may
overlap; each candidate placement is checked against the map's drivable area with the shuttle's
half-width on both sides, and the first that stays on the road is kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from matplotlib.path import Path as MplPath

from lastmile.core.errors import RoutingError
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.model import DRIVABLE_SUBTYPES, HDMap

COMFORT_LATERAL_ACCEL_MPS2 = 1.0
"""Peak lateral acceleration of the lane change itself: the comfort bound the speed profile applies to
curvature (``control.velocity_profile.VelocityProfileConfig.max_lateral_accel_mps2``)."""
STEER_SHARE = 0.5
"""The lane change may use at most this share of the vehicle's tightest curvature (the road's own curve
and the tracking error need the rest)."""
QUINTIC_PEAK = 10.0 / math.sqrt(3.0)
"""max |d²σ/du²| of the quintic smoothstep σ(u) = 10u³ - 15u⁴ + 6u⁵ on [0, 1]."""
LENGTH_SHARES = (1.0, 0.8, 0.65, 0.5)
"""Shorter transitions tried (as shares of the comfortable length) when the longer ones leave the road."""
CENTRE_SHIFTS = tuple(sorted((k / 10.0 for k in range(-15, 16)), key=abs))
"""Where the transition's centre is tried, in transition lengths from the mapped change point."""
SAMPLE_M = 0.25  # vertex spacing inside a transition
SMOOTH_SIGMA_M = 1.0
"""Along-line scale of the smoothing over a transition: removes a heading kink of a few degrees where
two lanes meet at an angle, and moves a curve of 20 m radius inwards by about sigma² / 2R = 2.5 cm."""


@dataclass(frozen=True, slots=True, kw_only=True)
class KeepClear:
    """A stretch of the route a lane change should stay out of (a stop's platform): centred on the
    route vertex nearest (x_m, y_m), ``half_length_m`` either way, on lanelet ``lanelet_id``. A change
    into that lanelet should end before the stretch, a change out of it begin after."""

    x_m: float
    y_m: float
    half_length_m: float
    lanelet_id: int


@dataclass(frozen=True, slots=True, kw_only=True)
class LaneJump:
    """A lane change in a stepped centre line: ``xy[index]`` is the first vertex on the new lane.

    Attributes:
        index: first vertex after the jump.
        speed_mps: the speed limit of the lanelet left (sets the comfortable length).
    """

    index: int
    speed_mps: float
    from_lanelet_id: int = 0
    to_lanelet_id: int = 0


def comfortable_length_m(width_m: float, speed_mps: float, geometry: VehicleGeometry) -> float:
    """Transition length for a lateral shift ``width_m`` at ``speed_mps``: peak curvature
    QUINTIC_PEAK * w / L² at most a_comfort / v², and at most STEER_SHARE of the tightest the vehicle
    steers."""
    kappa_steer = STEER_SHARE * math.tan(geometry.max_steer_rad) / geometry.wheelbase_m
    kappa = min(COMFORT_LATERAL_ACCEL_MPS2 / max(speed_mps, 1e-3) ** 2, kappa_steer)
    return math.sqrt(QUINTIC_PEAK * abs(width_m) / kappa)


def min_length_m(width_m: float, geometry: VehicleGeometry) -> float:
    """The shortest transition the vehicle can steer (STEER_SHARE of its tightest curvature)."""
    kappa_steer = STEER_SHARE * math.tan(geometry.max_steer_rad) / geometry.wheelbase_m
    return math.sqrt(QUINTIC_PEAK * abs(width_m) / kappa_steer)


def smooth_lane_changes(
    hdmap: HDMap,
    xy: np.ndarray,
    jumps: list[LaneJump],
    closed: bool,
    geometry: VehicleGeometry | None = None,
    keep_clear: tuple[KeepClear, ...] = (),
) -> np.ndarray:
    """Replace each jump of the stepped centre line ``xy`` ((N, 2), jumps included) by a transition.

    Placements are ranked: on the road first, then clear of ``keep_clear`` stretches, then clear of
    changes the other way, then the longest, then the nearest the mapped change point.

    Returns:
        (M, 2) the smooth centre line (closed lines without the repeated first vertex).
    """
    geometry = geometry or VehicleGeometry()
    at, xy = _densify(xy, jumps, closed)
    # Arc length along the lanes: a jump is a step sideways, not distance driven.
    seg = np.hypot(*np.diff(xy, axis=0).T)
    is_jump = np.zeros(len(seg), dtype=bool)
    for k in at:
        is_jump[k - 1] = True
    arc = np.concatenate([[0.0], np.cumsum(np.where(is_jump, 0.0, seg))])
    total = float(arc[-1])  # a closed line repeats its first vertex at the end
    tangent = _tangents(xy, is_jump)
    for k in at:
        # Both sides of a jump share one frame, so every transition's offsets meet exactly there.
        mean = tangent[k - 1] + tangent[k]
        tangent[k - 1] = tangent[k] = mean / np.hypot(*mean)
    normal = np.c_[-tangent[:, 1], tangent[:, 0]]
    steps = [xy[k] - xy[k - 1] for k in at]
    widths = [float(step @ normal[k]) for step, k in zip(steps, at, strict=True)]
    # Until a change is placed, its window is taken at its mapped point with its comfortable length.
    windows = [
        (float(arc[k]), comfortable_length_m(w, j.speed_mps, geometry))
        for k, w, j in zip(at, widths, jumps, strict=True)
    ]
    clear = [
        (
            float(arc[int(np.argmin(np.hypot(xy[:, 0] - kc.x_m, xy[:, 1] - kc.y_m)))]),
            kc.half_length_m,
            kc.lanelet_id,
        )
        for kc in keep_clear
    ]
    road = RoadOutline(hdmap)
    out = xy.copy()
    for n, (k, jump, step) in enumerate(zip(at, jumps, steps, strict=True)):
        before = np.array([step @ normal[k - 1], step @ tangent[k - 1]])
        after = np.array([step @ normal[k], step @ tangent[k]])
        # Windows of changes the other way (in, then out again): overlapping them makes an S-bend.
        against = [win for m, win in enumerate(windows) if m != n and widths[m] * widths[n] < 0]
        best: tuple[tuple[int, float, float, int, float], np.ndarray, float, float] | None = None
        for rank, length in enumerate(_lengths(widths[n], jump.speed_mps, geometry)):
            for shift in CENTRE_SHIFTS:
                centre = float(arc[k]) + shift * length
                overlap = sum(_overlap_m(centre, length, c, ln, total, closed) for c, ln in against)
                on_stop = sum(_stop_conflict_m(centre, length, jump, kc, total, closed) for kc in clear)
                if best is not None and best[0][:3] == (0, 0.0, 0.0):
                    break
                cand = out + _correction(
                    arc, k, centre, length, before, after, tangent, normal, total, closed
                )
                off = _off_road(road, cand, normal, arc, centre, length, geometry, total, closed)
                key = (off, round(on_stop, 3), round(overlap, 3), rank, abs(shift))
                if best is None or key < best[0]:
                    best = (key, cand, centre, length)
        assert best is not None
        out = best[1]
        windows[n] = (best[2], best[3])
    # A transition placed away from its jump leaves the lanes' meeting point (two lines at an angle)
    # outside its window: the smoothing covers both.
    spans = []
    for (centre, length), k in zip(windows, at, strict=True):
        d = float(_signed_from(np.array([arc[k]]), centre, total, closed)[0])
        lo, hi = min(-length / 2.0, d), max(length / 2.0, d)
        spans.append((centre + (lo + hi) / 2.0, hi - lo))
    out = smooth_spans(out, arc, spans, total, closed)
    return out[:-1] if closed and np.hypot(*(out[0] - out[-1])) < 1e-9 else out


def smooth_spans(
    xy: np.ndarray,
    arc: np.ndarray,
    spans: list[tuple[float, float]],
    total: float,
    closed: bool,
    sigma_m: float = SMOOTH_SIGMA_M,
) -> np.ndarray:
    """Gaussian smoothing (``sigma_m`` along the line) over each (centre, length) span of arc: where
    two lanes meet at an angle (an outer lane bending away to an exit), the joined line has a heading
    kink that the lateral transition alone does not remove; ``corner_rounding`` uses it with a wider
    kernel on corners the vehicle cannot steer."""
    out = xy.copy()
    reach = 3.0 * sigma_m
    # Each vertex weighs the length of line it stands for: vertices crowded at a mapped point (or
    # the two ends of a jump, now one place) must not pull the average towards themselves.
    measure = np.gradient(arc)
    for centre, length in spans:
        src = out.copy()  # overlapping spans: each smooths what the last one left
        rel = _signed_from(arc, centre, total, closed)
        inside = np.flatnonzero(np.abs(rel) <= length / 2.0 + reach)
        # Neighbours a reach further out, so that no smoothed vertex sees a one-sided kernel.
        support = np.flatnonzero(np.abs(rel) <= length / 2.0 + 2.0 * reach)
        for i in inside.tolist():
            d = _signed_from(arc[support], float(arc[i]), total, closed)
            w = np.exp(-0.5 * (d / sigma_m) ** 2) * measure[support]
            # Full smoothing inside the transition, fading out (smoothly) over the reach beyond it.
            fade = float(_sigma(np.array([(length / 2.0 + reach - abs(float(rel[i]))) / reach]))[0])
            out[i] = (1.0 - fade) * src[i] + fade * (w[:, None] * src[support]).sum(axis=0) / w.sum()
    return out


def _stop_conflict_m(
    centre: float, length: float, jump: LaneJump, stop: tuple[float, float, int], total: float, closed: bool
) -> float:
    """Metres of a transition window that conflict with a stop's stretch: a change into the stop's
    lanelet should be over before the stretch, one out of it should start after, any other change
    should stay out of it."""
    s_centre, half, lanelet = stop
    rel = float(_signed_from(np.array([centre]), s_centre, total, closed)[0])
    start, end = rel - length / 2.0, rel + length / 2.0
    if lanelet == jump.to_lanelet_id:
        return max(0.0, end + half)
    if lanelet == jump.from_lanelet_id:
        return max(0.0, half - start)
    return max(0.0, min(end, half) - max(start, -half))


def _overlap_m(c1: float, l1: float, c2: float, l2: float, total: float, closed: bool) -> float:
    gap = abs(float(_signed_from(np.array([c1]), c2, total, closed)[0]))
    return max(0.0, (l1 + l2) / 2.0 - gap)


def _lengths(width_m: float, speed_mps: float, geometry: VehicleGeometry) -> list[float]:
    longest = comfortable_length_m(width_m, speed_mps, geometry)
    shortest = min_length_m(width_m, geometry)
    out = sorted({max(longest * share, shortest) for share in LENGTH_SHARES}, reverse=True)
    return out


def _sigma(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2)


def _signed_from(arc: np.ndarray, origin: float, total: float, closed: bool) -> np.ndarray:
    d = arc - origin
    if closed:
        d = (d + total / 2.0) % total - total / 2.0
    return d


def _correction(
    arc: np.ndarray,
    k: int,
    centre: float,
    length: float,
    before: np.ndarray,
    after: np.ndarray,
    tangent: np.ndarray,
    normal: np.ndarray,
    total: float,
    closed: bool,
) -> np.ndarray:
    """Offsets that turn the jump at vertex ``k`` into a transition centred at arc ``centre``.

    Before the jump the line moves towards the new lane by σ of the step, after it back towards the
    old one by 1 - σ: both sides meet where the jump was, whatever the centre.
    """
    idx = np.arange(len(arc))
    side = _signed_from(arc, float(arc[k]), total, closed)
    # σ in the same unwrapped coordinate as the side: on a loop both must wrap at the same vertex.
    sigma = _sigma((side - (centre - float(arc[k]))) / length + 0.5)
    # A vertex is before the jump when it lies behind it along the line (ties: by index).
    is_before = (side < 0) | ((side == 0) & (idx < k))
    lateral = np.where(is_before, before[0] * sigma, -after[0] * (1.0 - sigma))
    along = np.where(is_before, before[1] * sigma, -after[1] * (1.0 - sigma))
    # Only the half-lap either side matters; far vertices get no correction (sigma saturates anyway).
    return lateral[:, None] * normal + along[:, None] * tangent


class RoadOutline:
    """The drivable lanelets' outlines with their bounding boxes, for repeated point tests."""

    def __init__(self, hdmap: HDMap) -> None:
        polys = [
            hdmap.polygon_of(lid) for lid, ll in hdmap.lanelets.items() if ll.subtype in DRIVABLE_SUBTYPES
        ]
        self.paths = [MplPath(poly) for poly in polys]
        self.lo = np.array([poly.min(axis=0) for poly in polys]).reshape(-1, 2)
        self.hi = np.array([poly.max(axis=0) for poly in polys]).reshape(-1, 2)

    def contains(self, pts: np.ndarray) -> np.ndarray:
        """(N,) bool: the (N, 2) points on a drivable lanelet."""
        on_road = np.zeros(len(pts), dtype=bool)
        if not len(pts):
            return on_road
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        near = np.flatnonzero(np.all(self.lo <= hi, axis=1) & np.all(self.hi >= lo, axis=1))
        for k in near.tolist():
            todo = ~on_road
            if not todo.any():
                break
            on_road[todo] = self.paths[k].contains_points(pts[todo])
        return on_road


def _off_road(
    road: RoadOutline,
    xy: np.ndarray,
    normal: np.ndarray,
    arc: np.ndarray,
    centre: float,
    length: float,
    geometry: VehicleGeometry,
    total: float,
    closed: bool,
) -> int:
    """How many of the transition's vertices put the shuttle's side (half its width out) off the road.

    Tested against the drivable lanelets near the transition only (exact polygon tests): the map's
    raster would be built for the whole map, seconds on a large one, before the run needs it.
    """
    near = np.abs(_signed_from(arc, centre, total, closed)) <= length / 2.0 + geometry.length_m
    half = geometry.width_m / 2.0
    pts = np.vstack([xy[near] + half * normal[near], xy[near] - half * normal[near]])
    return int((~road.contains(pts)).sum())


def _tangents(xy: np.ndarray, is_jump: np.ndarray) -> np.ndarray:
    """(N, 2) unit tangents from the neighbouring segments that are not jumps."""
    d = np.diff(xy, axis=0)
    d[is_jump] = np.nan
    fwd = np.vstack([d, [np.nan, np.nan]])
    back = np.vstack([[np.nan, np.nan], d])
    t = np.nan_to_num(fwd) + np.nan_to_num(back)
    bad = np.hypot(*t.T) < 1e-12
    if bad.any():
        raise RoutingError("lane change: expected a centre line with length either side of a jump")
    return t / np.hypot(*t.T)[:, None]


def _densify(xy: np.ndarray, jumps: list[LaneJump], closed: bool) -> tuple[list[int], np.ndarray]:
    """Vertices every SAMPLE_M (original vertices kept; jumps stay jumps) and the jumps' new indices."""
    starts = sorted({j.index for j in jumps})
    runs = np.split(xy, starts)
    out: list[np.ndarray] = []
    new_idx: dict[int, int] = {}
    count = 0
    for r, run in enumerate(runs):
        if r > 0:
            new_idx[starts[r - 1]] = count
        if len(run) == 1:
            out.append(run)
            count += 1
            continue
        seg = np.hypot(*np.diff(run, axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        grid = np.arange(0.0, s[-1], SAMPLE_M)
        # Grid points crowding a mapped vertex would turn rounding into tangent noise: drop them.
        idx = np.clip(np.searchsorted(s, grid), 1, len(s) - 1)
        nearest = np.minimum(np.abs(grid - s[idx - 1]), np.abs(grid - s[idx]))
        fine = np.unique(np.concatenate([s, grid[nearest > SAMPLE_M / 4]]))
        pts = np.c_[np.interp(fine, s, run[:, 0]), np.interp(fine, s, run[:, 1])]
        out.append(pts)
        count += len(pts)
    dense = np.vstack(out)
    if closed:
        dense = np.vstack([dense, dense[:1]])
    return [new_idx[j.index] for j in jumps], dense
