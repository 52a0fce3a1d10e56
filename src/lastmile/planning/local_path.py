"""Local path: the route ahead, shifted by the potential field and by Bezier pull-over/merge curves."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from lastmile.core.geometry import FloatArray
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, StopReason, Trajectory
from lastmile.planning.behaviour_config import BehaviourConfig
from lastmile.planning.bezier import lateral_transition_m, smooth_through
from lastmile.planning.lattice_config import LatticeConfig
from lastmile.planning.pass_path_config import PassPathConfig
from lastmile.planning.potential_field import PotentialFieldConfig, nudge_offsets_m
from lastmile.planning.road_edge import STATION_M, BodyPlacement, DrivableLookup, RoadEdges, body_overhang_m


@dataclass(frozen=True, slots=True, kw_only=True)
class LocalPathConfig:
    """Extent and resolution of the local path.

    Attributes:
        behind_m, ahead_m: route length planned behind and ahead of the rear axle.
        waypoint_step_m: spacing of the shifted waypoints the Bezier chain passes through.
        pullover_m: route length of the lateral move into a bay; merge_m likewise out of it.
        settle_m: run along the curb between the end of the front's pull-over curve and the spot, in
            which the rear swings in parallel.
        lane_half_width_m: half the lane width used to bound the nudge when the map has no layer.
        curb_clearance_m: the least gap the planned body keeps to the curb, tapers included.
        route_anchored_waypoints: lay the shifted waypoints on route stations that are multiples of
            ``waypoint_step_m`` rather than starting at the rear axle. Off, the smoothed curve through
            them moves with the rear axle's position between two waypoints: through a bay's turn-in
            the planned path at a fixed place swings by up to 0.3 m from one 10 Hz cycle to the next
            (a 2 m period in the shuttle's position). A lookahead of 4 m and more averages that out; a
            law measured at the front axle or aiming 2-3 m ahead chases it off the road.
        rear_axle_on_spot: remove what the rear axle's lag still lacks of the pull-over spot's offset
            over the settling run, so that the path reaches the spot's line at the spot (off, it ended
            0.09 m short at S1, and a law tracking it exactly stopped 0.3 m from the curb).
        exact_body_clearance: check the pull-over's clearance with the body placed exactly along the
            path (off: to first order, which at S1's 0.4 rad turn-in put the front corner of a body
            tracking the path exactly over the taper's curb).
        floor_rounding_m: the curb floor the front's pull-over curve keeps to has its convex corners
            rounded over this length, never towards the curb: where a bay's taper meets its
            platform (a 1:2.5 taper turns 0.38 rad there) a plain maximum left a curvature spike in
            the path (0.12-0.14 /m, beyond what the front-steered shuttle follows at 3 m/s with
            1 m/s^2 of lateral acceleration; snow seed 2 put its front corner on the platform's
            curb). Over 8 m that turn asks about 0.05 /m (0.6 m/s^2 at the 3.5 m/s pull-over
            speed). Longer rounding ends the curve later: with 10 m the bay test's shuttle stood
            0.022 rad off parallel (tests/stack: at most 0.02).
        keep_on_road: keep the merge's whole body on the map's drivable area (``curb_clearance_m``
            inside its unkerbed edge), with the body placed exactly along the path
            (:mod:`lastmile.planning.road_edge`): where it would not be, the path is lifted away from
            the edge (BITS loop, CP: held by rear traffic, the merge restarted where the shuttle stood
            and it crept out along the kerb into a kerb coming in; its corner left the road).
        edge_lift_slope: how steeply that lift rises and falls along the route (1:5): rounded over
            ``floor_rounding_m`` it asks at most 2 x 0.2 / 8 m = 0.05 /m of curvature, what the
            rounded curb floor above asks.
        field: the potential field's parameters.
        passing: the offset-pass planner's (``planner = "offset_pass"``; :mod:`lastmile.planning.pass_path`).
        behaviour: Snow Lion's behaviour planner's (``planner = "snow_lion_behaviour"``;
            :mod:`lastmile.planning.snow_lion_behaviour`; None: its defaults, and the run's
            configuration echo stays as it was before the planner existed).
        lattice: aUToronto's lattice planner's (``planner = "lattice"``;
            :mod:`lastmile.planning.lattice_planner`; None: its defaults, the echo unchanged).
    """

    behind_m: float = 5.0
    ahead_m: float = 60.0
    waypoint_step_m: float = 2.0
    pullover_m: float = 20.0
    settle_m: float = 8.0
    merge_m: float = 18.0
    lane_half_width_m: float = 1.75
    curb_clearance_m: float = 0.08
    route_anchored_waypoints: bool = False
    rear_axle_on_spot: bool = False
    exact_body_clearance: bool = False
    floor_rounding_m: float = 8.0
    keep_on_road: bool = True
    edge_lift_slope: float = 0.2
    # Before ``field``: that attribute's name hides dataclasses.field further down the class body.
    passing: PassPathConfig = field(default_factory=PassPathConfig)
    behaviour: BehaviourConfig | None = None
    lattice: LatticeConfig | None = None
    field: PotentialFieldConfig = field(default_factory=PotentialFieldConfig)


CurbLookup = Callable[[FloatArray], FloatArray]


class LocalPathPlanner:
    """Plans the geometric path each planning cycle (10 Hz); speed is left to the controller.

    With ``curb_right_d_m`` (route s -> signed curb offset, NaN where there is none) the pull-over and
    merge curves are pushed away from the curb wherever the body (``body_behind_m`` behind the path
    point to ``body_ahead_m`` ahead of it) would come closer than ``curb_clearance_m``: a bay's taper
    is shallower than its platform, and a curve that starts early would cut it.
    """

    def __init__(
        self,
        route: Polyline,
        half_width_m: float,
        config: LocalPathConfig | None = None,
        curb_right_d_m: CurbLookup | None = None,
        body_behind_m: float = 0.0,
        body_ahead_m: float = 0.0,
        drivable: DrivableLookup | None = None,
        body: BodyPlacement | None = None,
    ) -> None:
        self.route = route
        self.half_width_m = half_width_m
        self.config = config or LocalPathConfig()
        self.curb_right_d_m = curb_right_d_m
        self.drivable = drivable
        self.body = body
        self._edges = (
            RoadEdges(route, drivable, curb_right_d_m) if drivable is not None and body is not None else None
        )
        self._body_offsets = np.linspace(
            -body_behind_m, body_ahead_m, max(2, round(body_ahead_m + body_behind_m) * 2 + 1)
        )

    def offsets_m(
        self, s_m: FloatArray, decision: BehaviourDecision, obstacles: list[RouteObstacle], ego_d_m: float
    ) -> FloatArray:
        """Lateral offset d(s) from the route for the decision's state."""
        c = self.config
        spot_d = self._spot_d(decision)
        if decision.state in (BehaviourState.PULLOVER, BehaviourState.ONBOARDING) and spot_d is not None:
            assert decision.pullover_spot is not None
            spot_rear_s = self.route.project(
                decision.pullover_spot.x_m,
                decision.pullover_spot.y_m,
                hint_s_m=float(s_m[0]) + 30.0,
                window_m=80.0,
            ).s_m
            # End the curve a few metres before the spot so the last stretch is straight and parallel to
            # the curb: a lookahead controller needs that run to settle its lateral error before stopping.
            s1 = _unwrap_near(spot_rear_s, float(s_m[0]), self.route) - c.settle_m
            return self._off_the_curb(s_m, self._pullover_offsets_m(s_m, s1 - c.pullover_m, s1, spot_d))
        if decision.stop_reason == StopReason.MINIMAL_RISK_MANOEUVRE and spot_d is not None:
            # The safety module's pull-over: the same move to the curb as into a bay, to its spot.
            assert decision.pullover_spot is not None
            spot_rear_s = self.route.project(
                decision.pullover_spot.x_m, decision.pullover_spot.y_m, hint_s_m=float(s_m[0]), window_m=80.0
            ).s_m
            s1 = _unwrap_near(spot_rear_s, float(s_m[0]), self.route) - c.settle_m
            return self._off_the_curb(s_m, self._pullover_offsets_m(s_m, s1 - c.pullover_m, s1, spot_d))
        if decision.state == BehaviourState.MERGING and decision.merge_from_s_m is not None:
            start_d = spot_d if spot_d is not None else ego_d_m
            s0 = _unwrap_near(decision.merge_from_s_m, float(s_m[0]), self.route)
            d = self._off_the_curb(s_m, lateral_transition_m(s_m, s0, s0 + c.merge_m, start_d, 0.0))
            stood_s = s0
            if decision.pullover_spot is not None:
                spot = decision.pullover_spot
                at = self.route.project(spot.x_m, spot.y_m, hint_s_m=s0, window_m=40.0).s_m
                stood_s = _unwrap_near(at, float(s_m[0]), self.route)
            return self._on_the_road(s_m, d, from_s_m=stood_s + float(np.ptp(self._body_offsets)))
        if decision.state == BehaviourState.EMERGENCY_STOP and abs(ego_d_m) > 0.5:
            return np.full_like(s_m, ego_d_m)
        return nudge_offsets_m(
            s_m, obstacles, self.half_width_m, c.lane_half_width_m, -c.lane_half_width_m, c.field
        )

    def plan(
        self,
        stamp: Stamp,
        ego_s_m: float,
        ego_d_m: float,
        decision: BehaviourDecision,
        obstacles: list[RouteObstacle],
    ) -> Trajectory:
        c = self.config
        s0 = ego_s_m - c.behind_m
        if c.route_anchored_waypoints:
            # The same route stations every cycle: the curve through them no longer moves with the
            # rear axle's phase between two waypoints (it did by up to 0.3 m in a bay's turn-in).
            s0 = math.floor(s0 / c.waypoint_step_m) * c.waypoint_step_m
        s = np.arange(s0, ego_s_m + c.ahead_m + 1e-9, c.waypoint_step_m)
        d = self.offsets_m(s, decision, obstacles, ego_d_m)
        base = self.route.points_at(s)
        headings = _headings(base, self.route.closed)
        way = base + d[:, None] * np.c_[-np.sin(headings), np.cos(headings)]
        xy = smooth_through(way, samples_per_segment=2)
        seg = np.diff(xy, axis=0)
        ds = np.hypot(seg[:, 0], seg[:, 1])
        keep = np.r_[True, ds > 1e-6]
        xy = xy[keep]
        seg = np.diff(xy, axis=0)
        ds = np.hypot(seg[:, 0], seg[:, 1])
        yaw = np.r_[np.arctan2(seg[:, 1], seg[:, 0]), math.atan2(seg[-1, 1], seg[-1, 0])]
        dyaw = (np.diff(yaw) + np.pi) % (2 * np.pi) - np.pi
        kappa = np.r_[dyaw / np.maximum(ds, 1e-6), 0.0]
        path_s = np.r_[0.0, np.cumsum(ds)]
        points = np.c_[xy, yaw, kappa, path_s]
        return Trajectory(stamp=stamp, points=points, route_s0_m=float(s[0]))

    def _pullover_offsets_m(self, s_m: FloatArray, s0_m: float, s1_m: float, spot_d_m: float) -> FloatArray:
        """Rear-axle offsets whose body front never swings past the spot line.

        A rigid body whose rear axle follows d(s) puts its front, l metres ahead, at about
        d + l d'(s); on a curve that flattens onto the curb line that overshoots by up to 3 D l^2 / L^2
        (0.37 m for D = 3.5 m, l = 3.75 m, L = 20 m). So the Bezier is laid for the front, and the rear
        axle's offsets are its first-order lag over l (d + l d' = front): the body then approaches the
        curb front first and swings in parallel, never crossing the line, as a bus driver docks.
        """
        ahead = float(self._body_offsets[-1])
        if ahead <= 0.0:
            return lateral_transition_m(s_m, s0_m, s1_m, 0.0, spot_d_m)
        step = 0.25
        grid = np.arange(s0_m - step, max(float(s_m[-1]), s0_m) + step, step)
        front = lateral_transition_m(grid + ahead, s0_m, s1_m, 0.0, spot_d_m)
        if self.curb_right_d_m is not None:  # the front corner leads: it must not cut the taper either
            curb = self.curb_right_d_m(grid + ahead)
            floor = np.where(np.isnan(curb), -np.inf, curb) + self.config.curb_clearance_m + self.half_width_m
            front = np.maximum(front, rounded_floor_m(floor, step, self.config.floor_rounding_m))
        alpha = 1.0 - math.exp(-step / ahead)
        rear = lfilter([alpha], [1.0, alpha - 1.0], front)  # rear += alpha * (front - rear), from 0
        if self.config.exact_body_clearance and self.curb_right_d_m is not None:
            rear = self._clear_of_the_curb(grid, front, rear, alpha)
        if self.config.rear_axle_on_spot:
            lagged = rear
            toward = rear - _lag_residual_m(grid, rear, s1_m, s1_m + self.config.settle_m, spot_d_m)
            side = math.copysign(1.0, -spot_d_m)  # the side of the spot line the path comes from
            rear = spot_d_m + side * np.maximum(side * (toward - spot_d_m), 0.0)  # never past the line
            if self.config.exact_body_clearance and self.curb_right_d_m is not None:
                rear = self._spot_kept_clear(grid, rear, lagged)
        return np.where(s_m < grid[0], 0.0, np.interp(s_m, grid, rear))

    def _clear_of_the_curb(
        self, grid: FloatArray, front: FloatArray, rear: FloatArray, alpha: float
    ) -> FloatArray:
        """Lift the front's curve until the right side of the rigid body, placed exactly (rear axle on
        the path, body along its tangent), keeps ``curb_clearance_m`` from the curb.

        The front's floor above holds only to first order: at the 0.4 rad of S1's turn-in the front
        corner sits l (1 - cos psi) = 0.3 m further back than d + l d' assumes, where the taper is
        shallower, and a law that tracked the path exactly put that corner over the curb. Each pass
        raises the front by the worst shortfall of the body side over the next ``ahead`` metres and
        lags the rear anew; a few passes converge (the lift only moves the path away from the curb).
        """
        span = max(1, round(float(self._body_offsets[-1]) / (grid[1] - grid[0])))
        lift = np.zeros_like(front)
        for _ in range(6):
            short = self._curb_shortfall_m(grid, rear)
            if not np.any(short > 1e-3):
                break
            # The front at grid i leads the rear by ``ahead``: lift it over the stretch whose body
            # reaches the shortfall.
            need = np.maximum(short, 0.0)
            padded = np.concatenate([need, np.zeros(span)])
            ahead_need = np.lib.stride_tricks.sliding_window_view(padded, span + 1).max(axis=1)
            lift = lift + ahead_need
            rear = lfilter([alpha], [1.0, alpha - 1.0], front + lift)
        return rear

    def _curb_shortfall_m(self, grid: FloatArray, rear: FloatArray) -> FloatArray:
        """At each station, how far the right side of the body placed exactly (rear axle at ``rear``,
        body along the path's tangent) comes inside ``curb_clearance_m`` of the curb (-inf: no curb)."""
        assert self.curb_right_d_m is not None
        along = self._body_offsets  # rear overhang .. front, on the body axis
        half = self.half_width_m
        psi = np.arctan(np.gradient(rear, grid))
        cos, sin = np.cos(psi)[:, None], np.sin(psi)[:, None]
        side_s = grid[:, None] + along[None, :] * cos + half * sin
        side_d = rear[:, None] + along[None, :] * sin - half * cos
        curb = self.curb_right_d_m(side_s.ravel()).reshape(side_s.shape)
        return np.where(np.isnan(curb), -np.inf, curb + self.config.curb_clearance_m - side_d).max(axis=1)

    def _spot_kept_clear(self, grid: FloatArray, rear: FloatArray, lagged: FloatArray) -> FloatArray:
        """The rear-axle offsets brought onto the spot's line, lifted again wherever that took the body
        inside the curb clearance.

        Bringing the rear axle onto the line over the settling run also turns the body toward the curb
        while its front corner is still angled at the platform: at S1 that ate the whole clearance the
        lift above had made (the plan's front corner on the kerb in the first-bay scenario in snow, and
        on the second lap in clear, for every law that tracks the path closely). Each pass lifts by a
        tent over the shortfall (as ``_on_the_road``), never beyond ``lagged`` (the offsets before the
        correction, which kept the clearance): the lift gives back part of the correction, no more.
        """
        c = self.config
        step = float(grid[1] - grid[0])
        ceiling = np.maximum(lagged, rear)
        lift = np.zeros_like(rear)
        kept = rear
        for _ in range(ROAD_PASSES):
            need = np.maximum(self._curb_shortfall_m(grid, kept), 0.0)
            if not np.any(need > ROAD_TOLERANCE_M):
                break
            lift = lift + _tent_lift_m(need, step, c.edge_lift_slope, c.floor_rounding_m)
            kept = np.minimum(rear + lift, ceiling)
        return kept

    def _on_the_road(self, s_m: FloatArray, d_m: FloatArray, from_s_m: float = -math.inf) -> FloatArray:
        """The merge's ``d_m`` lifted (leftwards) wherever the body placed along the path, with its rear
        axle from ``from_s_m`` on (where the body has left the place it stood at the stop), would come
        within ``curb_clearance_m`` of the road's right edge.

        Only the merge: at the spot the stop's own placement governs (``hdmap.service_route``: the
        straight body at rest keeps the door gap along the whole kerb), and on the pull-over's
        approach through a bend a body placed on the rear axle's tangent is not how the lookahead
        laws drive it (they cut the bend's inside): at the Lanelet2 example's Roundabout West it
        asked a 0.45 m lift the shuttle never needed and left the door 0.54 m from the kerb.

        Each pass measures the worst overhang of the body at every station and lifts by
        ``_tent_lift_m`` (at least the overhang everywhere, bounded slope and curvature); the lift
        changes the body's heading, so it is measured again.
        """
        c = self.config
        if self._edges is None or self.body is None or not c.keep_on_road:
            return d_m
        grid = np.arange(float(s_m[0]), float(s_m[-1]) + 1e-9, STATION_M)
        d = np.interp(grid, s_m, d_m)
        lift = np.zeros_like(d)
        for _ in range(ROAD_PASSES):
            (over,) = body_overhang_m(self.route, self._edges, self.body, grid, d + lift, c.curb_clearance_m)
            need = np.where(grid >= from_s_m, np.maximum(over, 0.0), 0.0)
            if not np.any(need > ROAD_TOLERANCE_M):
                break
            lift = lift + _tent_lift_m(need, STATION_M, c.edge_lift_slope, c.floor_rounding_m)
        if not np.any(lift > 0.0):
            return d_m
        return d_m + np.interp(s_m, grid, lift)

    def _off_the_curb(self, s_m: FloatArray, d_m: FloatArray) -> FloatArray:
        if self.curb_right_d_m is None:
            return d_m
        curb = self.curb_right_d_m((s_m[:, None] + self._body_offsets[None, :]).ravel()).reshape(len(s_m), -1)
        curb = np.where(np.isnan(curb), -np.inf, curb)  # no curb (an opening): nothing to keep off
        floor = curb.max(axis=1) + self.config.curb_clearance_m + self.half_width_m
        return np.maximum(d_m, floor)

    def _spot_d(self, decision: BehaviourDecision) -> float | None:
        spot = decision.pullover_spot
        if spot is None:
            return None
        return self.route.project(spot.x_m, spot.y_m).d_m


def _lag_residual_m(
    grid: FloatArray, rear: FloatArray, s1_m: float, spot_s_m: float, spot_d_m: float
) -> FloatArray:
    """What the lagged rear axle still lacks of the spot's offset at the spot, faded in from ``s1_m``.

    A first-order lag never quite arrives: held out by a bay's taper, the front reaches the platform
    line late and the rear axle was 0.09 m short of it at S1's spot, so a law tracking the path exactly
    stopped 0.3 m from the curb. Removing the residual along a smoothstep over the settling run brings
    the rear axle onto the spot's line at the spot (the caller clamps the result at the line).
    """
    residual = float(np.interp(spot_s_m, grid, rear)) - spot_d_m
    t = np.clip((grid - s1_m) / max(spot_s_m - s1_m, 1e-6), 0.0, 1.0)
    return residual * t * t * (3.0 - 2.0 * t)


ROAD_PASSES = 4
"""Lift-and-measure passes of ``_on_the_road`` (each lift only moves the body away from the edge)."""
ROAD_TOLERANCE_M = 0.005
"""An overhang below this is measurement noise (the edge is probed to 0.016 m)."""


def _tent_lift_m(need_m: FloatArray, step_m: float, slope: float, length_m: float) -> FloatArray:
    """A smooth lift covering ``need_m`` (sampled every ``step_m``): each need held flat over
    ``length_m`` centred on it, the sides of the result sloped at ``slope``, then averaged over
    ``length_m``. The window about a station lies wholly under its held need, so the mean covers it
    (no more: a wide need is lifted by itself, not more); the result's slope is at most ``slope`` and
    its curvature at most 2 slope / length."""
    if not np.any(need_m > 0.0):
        return np.zeros_like(need_m)
    half = max(round(0.5 * length_m / step_m), 0)
    window = 2 * half + 1
    held = np.lib.stride_tricks.sliding_window_view(np.pad(need_m, half), window).max(axis=1)
    x = np.arange(len(need_m)) * step_m
    hit = np.flatnonzero(held > 0.0)
    tent = np.max(held[hit][None, :] - slope * np.abs(x[:, None] - x[hit][None, :]), axis=1)
    tent = np.maximum(tent, 0.0)
    return np.lib.stride_tricks.sliding_window_view(np.pad(tent, half), window).mean(axis=1)


def rounded_floor_m(floor_m: FloatArray, step_m: float, length_m: float) -> FloatArray:
    """``floor_m`` (offsets sampled every ``step_m``) with its convex corners rounded over ``length_m``:
    the larger of the floor and its running mean. The mean of a straight stretch is itself, so tapers
    are not moved; at a corner where the floor flattens out (a taper meeting its platform) the mean
    lies above it and replaces the kink by a parabola; nothing is lowered. Where part of the window
    has no curb (-inf) the mean is taken over the samples that have one."""
    half = max(round(0.5 * length_m / step_m), 0)
    if half == 0 or len(floor_m) == 0:
        return floor_m
    padded = np.pad(floor_m, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    finite = np.isfinite(windows)
    count = finite.sum(axis=1)
    mean = np.where(finite, windows, 0.0).sum(axis=1) / np.maximum(count, 1)
    return np.maximum(floor_m, np.where(count > 0, mean, -np.inf))


def _headings(points: FloatArray, closed: bool) -> FloatArray:
    seg = np.diff(points, axis=0)
    h = np.arctan2(seg[:, 1], seg[:, 0])
    return np.r_[h, h[-1]]


def _unwrap_near(s_m: float, reference_s_m: float, route: Polyline) -> float:
    """Express a loop's s in the same lap as ``reference_s_m`` (the planning grid is not wrapped)."""
    if not route.closed:
        return s_m
    return reference_s_m + route.ds_m(reference_s_m, s_m)
