"""The road's edges along the route, and how far a body placed along a planned path is over them.

A kerbside stop's pull-over and the merge out of it move the shuttle towards the road's right edge;
where that stretch runs through a bend, the body's corners swing out beyond the rear axle's line by
up to l^2 kappa / 2 (3.75 m to the front corner at 0.2 /m: 1.4 m), more than a lateral offset laid in
route coordinates shows. On the BITS loop the move into E Block ran through a hairpin and the
front-right corner left the road (issue #18). Here the road's edge is found on the map's drivable area
(the surface the referee judges), and the body is placed exactly along the path (in map coordinates,
as the controller will drive it) so that the planner can keep the whole body on the road.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lastmile.core.geometry import FloatArray
from lastmile.core.polyline import Polyline

DrivableLookup = Callable[[FloatArray], np.ndarray]
"""(N, 2) map points -> (N,) bool: on the drivable road surface."""
CurbLookup = Callable[[FloatArray], FloatArray]
"""(N,) route s -> (N,) signed curb offset, NaN where none is mapped."""

STATION_M = 0.5
"""Route spacing of the edge probes (the body is checked every half metre too)."""
COARSE_M = 0.25
"""First pass of the probes across the road: the map raster's cell."""
REFINE_STEPS = 4
"""Bisections of the coarse bracket: the edge to COARSE_M / 2**4 = 0.016 m."""
REACH_M = 8.0
"""How far either side of the route the edge is looked for (a lane and a half; beyond it the body
never reaches during a pull-over)."""
PROJECT_WINDOW_M = 5.0
"""A body point is projected on the route within this of the route s its place along the body gives."""
SAMPLE_M = 0.5
"""Route samples searched for a body point's nearest."""
BODY_STEP_M = 0.5
"""Spacing of the points checked along each side of the body."""


@dataclass(frozen=True, slots=True, kw_only=True)
class BodyPlacement:
    """How the body lies along a planned path.

    Attributes:
        behind_m, ahead_m: the body's extent behind and ahead of the path point (rear overhang, and
            wheelbase plus front overhang, for a rear axle on the path).
        half_width_m: half the body's width.
        wheelbase_m: rear to front axle.
        rear_steer_above_1pm: where the route bends more than this (``rear_steers``), the rear wheels
            steer too and the centre of the wheelbase (not the rear axle) stays on the path; None:
            never (a front-steered vehicle).
    """

    behind_m: float
    ahead_m: float
    half_width_m: float
    wheelbase_m: float
    rear_steer_above_1pm: float | None = None


class RoadEdges:
    """The drivable area's edges either side of the route, probed on demand and kept per station.

    ``right_d_m(s)`` is the signed offset (negative: right of the route) of the first point off the
    drivable area found walking right from the route at s; ``left_d_m`` likewise to the left. Where the
    route point itself is off the road (a mapped line cutting a corner) there is no edge: NaN. An edge
    beyond ``REACH_M`` is reported at ``REACH_M``.

    With ``mapped_curb`` (route s -> the curb layer's offset, NaN where none is mapped) the right edge
    is NaN wherever a curb is mapped: there the planner's curb floor keeps the body off it, laid for
    the lookahead laws' wider line (a body placed exactly on the built-in campus's bay paths comes up
    to 0.5 m over a taper's drivable edge that the shuttles never touch). This check is for the edges
    no curb layer describes: a road's unkerbed end, a kerbside stop's approach on a map without curbs.
    """

    def __init__(
        self, route: Polyline, drivable: DrivableLookup, mapped_curb: CurbLookup | None = None
    ) -> None:
        self.route = route
        self.drivable = drivable
        self.mapped_curb = mapped_curb
        n = max(1, math.ceil(route.length_m / STATION_M) + 1)
        self._right = np.full(n, np.inf)  # inf: not probed yet
        self._left = np.full(n, np.inf)

    def _stations(self, s_m: FloatArray) -> np.ndarray:
        s = np.asarray(s_m, dtype=float)
        s = s % self.route.length_m if self.route.closed else np.clip(s, 0.0, self.route.length_m)
        return np.clip(np.round(s / STATION_M).astype(np.int64), 0, len(self._right) - 1)

    def right_d_m(self, s_m: FloatArray) -> FloatArray:
        """(N,) signed offset of the road's right edge at route ``s_m`` (N,), NaN where unknown."""
        k = self._stations(s_m)
        self._probe(k, self._right, -1.0)
        return self._right[k]

    def left_d_m(self, s_m: FloatArray) -> FloatArray:
        """(N,) signed offset of the road's left edge at route ``s_m`` (N,), NaN where unknown."""
        k = self._stations(s_m)
        self._probe(k, self._left, 1.0)
        return self._left[k]

    def _probe(self, k: np.ndarray, table: FloatArray, side: float) -> None:
        todo = np.unique(k[np.isinf(table[k])])
        if len(todo) == 0:
            return
        s = todo * STATION_M
        base = self.route.points_at(s)
        heading = _headings_at(self.route, s)
        normal = side * np.c_[-np.sin(heading), np.cos(heading)]  # towards the probed side
        steps = np.arange(0.0, REACH_M + 1e-9, COARSE_M)
        probes = base[:, None, :] + steps[None, :, None] * normal[:, None, :]
        on = self.drivable(probes.reshape(-1, 2)).reshape(len(todo), len(steps))
        off_any = ~on.all(axis=1)
        first_off = np.where(off_any, np.argmin(on, axis=1), len(steps))
        inside = first_off > 0
        # Bisect between the last coarse probe on the road and the first off it.
        lo = np.where(inside, steps[np.maximum(first_off - 1, 0)], 0.0)
        hi = np.where(off_any, steps[np.minimum(first_off, len(steps) - 1)], REACH_M)
        refine = inside & off_any
        for _ in range(REFINE_STEPS):
            if not refine.any():
                break
            mid = 0.5 * (lo + hi)
            ok = self.drivable(base + mid[:, None] * normal)
            lo = np.where(refine & ok, mid, lo)
            hi = np.where(refine & ~ok, mid, hi)
        edge = np.where(off_any, 0.5 * (lo + hi), REACH_M)
        edge = np.where(inside, side * edge, np.nan)
        if side < 0 and self.mapped_curb is not None:
            edge = np.where(np.isnan(self.mapped_curb(s)), edge, np.nan)
        table[todo] = edge


def rear_steers(
    route: Polyline, s_m: FloatArray, wheelbase_m: float, lead_m: float, limit_1pm: float
) -> np.ndarray:
    """(N,) bool: whether the route turns more than ``limit_1pm`` over some wheelbase-long stretch
    starting between the rear axle at ``s_m`` (N,) and ``lead_m`` ahead of it.

    The rear wheels are kept straight at a kerb (they would swing the tail into it), but a bend sharper
    than the route asks of the front wheels alone (``hdmap.corner_rounding.max_curvature_per_m``: a
    mapped corner too tight to round within the road) needs them: front-steered, the shuttle runs wide
    and its front corner leaves the road. The stack steers them there, and the planner places the body
    accordingly; both ask this function, over the same stretch.
    """
    s = np.asarray(s_m, dtype=float)
    starts = s[:, None] + np.arange(0.0, lead_m + 1e-9, STATION_M)[None, :]
    h0 = _headings_at(route, starts.ravel())
    h1 = _headings_at(route, starts.ravel() + wheelbase_m)
    turn = np.abs((h1 - h0 + math.pi) % (2 * math.pi) - math.pi).reshape(starts.shape)
    return np.asarray(turn.max(axis=1) > limit_1pm * wheelbase_m)


def _headings_at(route: Polyline, s_m: FloatArray, half_m: float = 0.5) -> FloatArray:
    """(N,) route heading at ``s_m``, from the chord over +-``half_m`` (smooth across vertices)."""
    a = route.points_at(np.asarray(s_m) - half_m)
    b = route.points_at(np.asarray(s_m) + half_m)
    return np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])


def path_xy(route: Polyline, s_m: FloatArray, d_m: FloatArray) -> tuple[FloatArray, FloatArray]:
    """((N, 2) points, (N,) headings) of the path d(s) laid on ``route`` at stations ``s_m`` (N,)."""
    heading = _headings_at(route, s_m)
    xy = route.points_at(s_m) + d_m[:, None] * np.c_[-np.sin(heading), np.cos(heading)]
    seg = np.gradient(xy, axis=0)
    return xy, np.arctan2(seg[:, 1], seg[:, 0])


def body_overhang_m(
    route: Polyline,
    edges: RoadEdges,
    body: BodyPlacement,
    s_m: FloatArray,
    d_m: FloatArray,
    margin_m: float,
    sides: tuple[float, ...] = (-1.0,),
) -> tuple[FloatArray, ...]:
    """How far the body placed at each station of the path d(s) is over the road's edges.

    The path's stations ``s_m`` (N,, increasing, about ``STATION_M`` apart) with offsets ``d_m`` (N,)
    are laid on the map; at each the body stands with its rear axle on the path and its axis along the
    path's tangent there (front steer), or, where the path bends more than
    ``body.rear_steer_above_1pm``, with the centre of the wheelbase on the path. Each point of its two
    sides is projected on the route and compared with the road's edge at that s.

    Args:
        sides: which sides to check, -1 right, +1 left.

    Returns:
        (N,) per side asked: metres by which the body's right (left) side comes within ``margin_m``
        of the road's right (left) edge, the worst point per station; 0 or negative: clear.
    """
    xy, yaw = path_xy(route, s_m, d_m)
    shift = np.zeros_like(s_m)
    if body.rear_steer_above_1pm is not None:
        steers = rear_steers(route, s_m, body.wheelbase_m, body.ahead_m, body.rear_steer_above_1pm)
        shift = np.where(steers, body.wheelbase_m / 2.0, 0.0)
    along = np.linspace(
        -body.behind_m, body.ahead_m, max(2, math.ceil((body.ahead_m + body.behind_m) / 0.5) + 1)
    )
    along = along[None, :] - shift[:, None]  # (N, K) from the path point
    cos, sin = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    out = []
    for side in sides:
        px = xy[:, :1] + along * cos - side * body.half_width_m * sin
        py = xy[:, 1:] + along * sin + side * body.half_width_m * cos
        ps, pd = _frenet(route, px.ravel(), py.ravel(), (s_m[:, None] + along).ravel())
        edge = edges.right_d_m(ps) if side < 0 else edges.left_d_m(ps)
        over = side * (pd - edge) + margin_m  # positive: within the margin of the edge, or past it
        over = np.where(np.isnan(over), -np.inf, over).reshape(px.shape)
        out.append(over.max(axis=1))
    return tuple(out)


def _frenet(
    route: Polyline, x_m: FloatArray, y_m: FloatArray, hint_s_m: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(s, d) of points on ``route``, each taken near its ``hint_s_m`` (within PROJECT_WINDOW_M): the
    nearest of route samples every SAMPLE_M there, then along that sample's tangent, twice (the
    second step leaves under kappa x (SAMPLE_M / 2)^2 / 2 of error: 2 mm at 0.27 /m)."""
    lo = float(hint_s_m.min()) - PROJECT_WINDOW_M
    n = math.ceil((float(hint_s_m.max()) + PROJECT_WINDOW_M - lo) / SAMPLE_M) + 1
    samples = route.points_at(lo + SAMPLE_M * np.arange(n, dtype=np.float64))
    reach = round(PROJECT_WINDOW_M / SAMPLE_M)
    idx = np.round((hint_s_m - lo) / SAMPLE_M).astype(np.int64)[:, None] + np.arange(-reach, reach + 1)
    idx = np.clip(idx, 0, n - 1)
    dist = (samples[idx, 0] - x_m[:, None]) ** 2 + (samples[idx, 1] - y_m[:, None]) ** 2
    s = lo + SAMPLE_M * idx[np.arange(len(idx)), np.argmin(dist, axis=1)]
    d = np.zeros_like(s)
    for _ in range(2):
        heading = _headings_at(route, s, half_m=0.25)
        base = route.points_at(s)
        dx, dy = x_m - base[:, 0], y_m - base[:, 1]
        t_x, t_y = np.cos(heading), np.sin(heading)
        step = np.clip(dx * t_x + dy * t_y, -SAMPLE_M, SAMPLE_M)
        d = t_x * dy - t_y * dx
        s = s + step
    return s, d
