"""Snow Lion's speed planning, wired: limits along the path, an s-t + QP profile, replanned on events.

Each planning cycle :meth:`StQpSpeedPlanning.update` builds, along the planned path ahead of the front
bumper,

- the speed limit (:mod:`lastmile.planning.speed_limits`): the route's / decision's / the path
  planner's cap, the curvature limit (eq. 1), the pedestrian-clearance limit (eq. 2: each pedestrian's
  gap to the body, less the width inflation, while the body is beside it) and the terminal stop (the
  nearest of decision's and the path planner's stop points);
- the predicted occupancy of the path by every road user at constant velocity (Snow Lion predicts
  with a constant velocity model): the stretch of path it covers while its footprint overlaps the
  shuttle's corridor (a lead car all the time, a crossing pedestrian while in the lane);

and replans (:class:`~lastmile.planning.st_speed.StSpeedPlanner`: s-t search, then the warm-started
OSQP piecewise-jerk QP) only on events, as Snow Lion does: no plan yet, the plan in use near its end
(``replan_remaining_s``), an interaction (a road user occupying the path within the horizon, or a
pedestrian-clearance limit below the cap: then every cycle, 10 Hz), or the stop point or cap moved.
:meth:`reference` gives the longitudinal controller the plan's speed ``lead_s`` ahead (the drive's
lag) and, when the plan comes to rest, the gap to where it does.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.vehicle_messages import BehaviourDecision, StopReason, Trajectory
from lastmile.planning.speed_limits import (
    ClearanceSpeedConfig,
    clearance_speed_limit_mps,
    combined_speed_limit_mps,
)
from lastmile.planning.st_speed import SpeedPlan, StObstacle, StSpeedConfig, StSpeedPlanner

STATIC_SPEED_MPS = 0.5
"""Road users slower than this are standing (decision's and the path planners' threshold)."""


class SpeedPlannerName(StrEnum):
    """Speed planners by name (the run configuration's ``[stack] speed_planner``)."""

    CONTROLLER = "controller"
    """The longitudinal controller's own law alone (its curvature limit and decision's stops)."""
    ST_QP = "st_qp"
    """Snow Lion's: limits (eqs. 1-2, terminal stop), s-t search over predicted road users and an
    OSQP piecewise-jerk QP, replanned on events; the controller tracks its speed."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SpeedPlanningConfig:
    """Parameters of :class:`StQpSpeedPlanning` (``[stack.speed_planning]``).

    Attributes:
        st: the s-t search and QP.
        clearance: eq. (2)'s thresholds and speeds.
        pedestrian_inflation_m: w_o added to a pedestrian's width in eq. (2) (the behaviour
            planner's common-road inflation).
        max_lateral_accel_mps2: eq. (1)'s a_lat (the longitudinal law's comfort bound).
        stop_decel_mps2: the terminal limit's deceleration (inside Snow Lion's -1.83 m/s^2).
        corridor_margin_m: a road user occupies the path while its footprint is within this of the
            shuttle's body sideways (the in-path test's margin).
        station_step_m: the limit's station spacing.
        replan_remaining_s: a plan with less than this left is replaced ("near its end").
        stop_moved_m, cap_moved_mps: a stop point moved, or a cap changed, by more than these is an
            event.
        lead_s: the reference is read this far ahead in the plan (the drive's ~0.25 s lag).
        rest_speed_mps: a plan whose last knot is slower than this comes to rest where it ends.
        stitch_tolerance_mps: a new plan starts from the plan in use while the measured speed is
            within this of it (Apollo's trajectory stitching), else from the measured state.
        urgent_decel_mps2: decision's stop point behind a followed road user binds the controller
            once holding it needs more than this (the longitudinal law's comfortable deceleration).
    """

    st: StSpeedConfig = field(default_factory=StSpeedConfig)
    clearance: ClearanceSpeedConfig = field(default_factory=ClearanceSpeedConfig)
    pedestrian_inflation_m: float = 0.5
    max_lateral_accel_mps2: float = 1.0
    stop_decel_mps2: float = 1.2
    corridor_margin_m: float = 0.5
    station_step_m: float = 1.0
    replan_remaining_s: float = 3.0
    stop_moved_m: float = 0.5
    cap_moved_mps: float = 0.1
    lead_s: float = 0.3
    rest_speed_mps: float = 0.3
    urgent_decel_mps2: float = 1.8
    stitch_tolerance_mps: float = 0.3

    def __post_init__(self) -> None:
        for name in ("max_lateral_accel_mps2", "stop_decel_mps2", "station_step_m", "replan_remaining_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"stack.speed_planning.{name}: expected a positive number, got {value}")
        if self.replan_remaining_s >= self.st.horizon_s:
            raise ConfigError(
                f"stack.speed_planning.replan_remaining_s: expected less than the horizon "
                f"({self.st.horizon_s} s), got {self.replan_remaining_s}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class SpeedInput:
    """What a planning cycle hands the speed planner.

    Attributes:
        now_s: the cycle's time.
        trajectory: the path planned this cycle.
        front_s_m: route s of the front bumper; path_s_m: the rear axle's station on the path.
        speed_mps, accel_mps2: the shuttle's speed and its last commanded acceleration.
        cap_mps: the lowest of decision's and the path planner's limits.
        stop_gap_m: the front's distance to the nearest stop point (None: none).
        obstacles: road users along the route.
        following: decision's stop point is behind a moving road user the plan follows.
    """

    now_s: float
    trajectory: Trajectory
    front_s_m: float
    path_s_m: float
    speed_mps: float
    accel_mps2: float
    cap_mps: float
    stop_gap_m: float | None
    obstacles: list[RouteObstacle]
    following: bool = False


FOLLOWED_REASONS = (StopReason.OBSTACLE, StopReason.CUT_IN)
"""Decision's stop points for a road user: when it moves, the s-t graph follows its prediction."""


def terminal_gap_m(
    decision: BehaviourDecision, obstacles: list[RouteObstacle], route: Polyline, front_s_m: float
) -> float | None:
    """The front's gap to decision's stop point as the plan's terminal stop, or None.

    A stop point behind a moving road user (decision's lead-car point: where it would stop braking)
    is not a terminal stop for the plan: the s-t search and the QP keep the gap and the headway to
    its constant-velocity prediction, as Snow Lion plans, and the longitudinal controller still gets
    decision's point as its safety limit.
    """
    if decision.stop_at_s_m is None:
        return None
    if decision.stop_reason in FOLLOWED_REASONS and any(
        o.track_id == decision.risk_track_id and o.speed_mps >= STATIC_SPEED_MPS for o in obstacles
    ):
        return None
    return route.ds_m(front_s_m, decision.stop_at_s_m)


class StQpSpeedPlanning:
    """The wired speed planner: builds its inputs, replans on events, hands out the reference."""

    def __init__(
        self,
        route: Polyline,
        half_width_m: float,
        body_length_m: float,
        front_from_rear_m: float,
        config: SpeedPlanningConfig | None = None,
    ) -> None:
        self.route = route
        self.config = c = config or SpeedPlanningConfig()
        self.half_width_m = half_width_m
        self.body_length_m = body_length_m
        self.front_from_rear_m = front_from_rear_m
        self.planner = StSpeedPlanner(c.st)
        self.plan: SpeedPlan | None = None
        self._plan_t0_s = 0.0
        self._plan_front_s = 0.0
        self._last_stop_gap: float | None = None
        self._last_cap = math.inf
        self._following = False
        self.replans = 0
        self.cycles = 0
        self.unsolved = 0

    def update(self, inp: SpeedInput) -> bool:
        """Replan if an event calls for it; returns whether it did."""
        c = self.config
        self.cycles += 1
        stations = np.arange(0.0, c.st.max_speed_mps * c.st.horizon_s + 10.0, c.station_step_m)
        obstacles = self._occupancy(inp)
        # A road user standing in the path is a terminal stop ``follow_gap_m`` behind it: the QP
        # alone approaches that bound ever more slowly and never comes to rest inside its horizon.
        standing = [
            float(ob.s_lo_m[0]) - c.st.follow_gap_m
            for ob, o in obstacles
            if o.speed_mps < STATIC_SPEED_MPS and ob.t_s[0] == 0.0
        ]
        if standing:
            stop = min(standing) if inp.stop_gap_m is None else min(inp.stop_gap_m, *standing)
            inp = dataclasses.replace(inp, stop_gap_m=stop)
        limit, clearance_binds = self._limits(inp, stations)
        due = self._due(inp, bool(obstacles) or clearance_binds)
        if not due:
            return False
        v0, a0 = self._start(inp)
        self.plan = self.planner.plan(stations, limit, v0, a0, [ob for ob, _ in obstacles])
        self.unsolved += not self.plan.solved
        self._plan_t0_s, self._plan_front_s = inp.now_s, inp.front_s_m
        self._last_stop_gap, self._last_cap = inp.stop_gap_m, inp.cap_mps
        self._following = inp.following
        self.replans += 1
        return True

    def reference(
        self, now_s: float, front_s_m: float, decision_gap_m: float | None, speed_mps: float
    ) -> tuple[float, float | None]:
        """(the plan's speed ``lead_s`` ahead, the stop gap for the longitudinal controller or None).

        The gap is the nearer of where the plan comes to rest for good and decision's stop point;
        decision's point behind a moving road user the plan follows (:func:`terminal_gap_m`) is handed
        on only once holding it needs more than ``urgent_decel_mps2`` (the plan has fallen behind
        events): otherwise the controller would brake for it while the plan keeps its own gap and
        headway, and the two laws would take turns (measured: +-0.66 m/s^2 every 3 s behind a car at
        3 m/s).
        """
        plan = self.plan
        if plan is None:
            return math.inf, decision_gap_m
        c = self.config
        t = now_s - self._plan_t0_s
        v = float(np.interp(t + c.lead_s, plan.t_s, plan.v_mps))
        gap = decision_gap_m
        if self._following and plan.solved and gap is not None:
            needed = max(speed_mps, 0.0) ** 2 / (2.0 * max(gap, 0.01))
            if needed <= c.urgent_decel_mps2:
                gap = None
        # A plan ending (nearly) at rest stops where it ends: the QP creeps on towards its bound at a
        # few cm/s rather than reaching rest inside its horizon, so the controller is handed that end
        # as its stop point (a plan that starts at rest and moves off is no stop).
        if float(plan.v_mps[-1]) < c.rest_speed_mps:
            rest = float(plan.s_m[-1]) - self._rel(self._plan_front_s, front_s_m)
            gap = rest if gap is None else min(gap, rest)
        return v, gap

    def _start(self, inp: SpeedInput) -> tuple[float, float]:
        """Where a new plan starts: the plan in use at this time while the shuttle tracks it within
        ``stitch_tolerance_mps`` (so the intent carries over: planned from the measured speed and the
        last command, each plan's first 0.3 s only extrapolated the drive's lag, and behind a car at
        3 m/s the speed swung between 2.1 and 4.6 m/s), else the measured speed and last command."""
        c = self.config
        # At rest the brake's hold (-1 m/s^2 commanded) is no motion: a plan from it could not
        # leave rest within its jerk limit.
        rest = inp.speed_mps < 0.05
        measured = (max(inp.speed_mps, 0.0), max(inp.accel_mps2, 0.0) if rest else inp.accel_mps2)
        plan = self.plan
        if plan is None or not plan.solved:
            return measured  # a fall-back stop is no intent to carry over
        t = inp.now_s - self._plan_t0_s
        if t > float(plan.t_s[-1]):
            return measured
        v = float(np.interp(t, plan.t_s, plan.v_mps))
        if abs(v - measured[0]) > c.stitch_tolerance_mps:
            return measured
        return max(v, 0.0), float(np.interp(t, plan.t_s, plan.a_mps2))

    # --- events -------------------------------------------------------------------------------------
    def _due(self, inp: SpeedInput, interacting: bool) -> bool:
        c = self.config
        if self.plan is None or interacting:
            return True
        left_s = float(self.plan.t_s[-1]) - (inp.now_s - self._plan_t0_s)
        if left_s < c.replan_remaining_s:
            return True
        if inp.cap_mps != self._last_cap and not abs(inp.cap_mps - self._last_cap) <= c.cap_moved_mps:
            return True  # (inf against a finite cap is a change too)
        old, new = self._last_stop_gap, inp.stop_gap_m
        if (old is None) != (new is None):
            return True
        if old is not None and new is not None:
            moved = new - (old - self._rel(self._plan_front_s, inp.front_s_m))
            return abs(moved) > c.stop_moved_m
        return False

    # --- inputs -------------------------------------------------------------------------------------
    def _limits(self, inp: SpeedInput, stations: np.ndarray) -> tuple[np.ndarray, bool]:
        """The combined limit at the front's stations, and whether eq. (2) binds below the cap."""
        c = self.config
        pts = inp.trajectory.points
        kappa = np.interp(inp.path_s_m + stations, pts[:, 4], np.abs(pts[:, 3]), right=0.0)
        clearance = self._pedestrian_clearance(inp, stations)
        stop = None if inp.stop_gap_m is None else max(inp.stop_gap_m, 0.0)
        cap = min(inp.cap_mps, c.st.max_speed_mps)
        limit = combined_speed_limit_mps(
            stations, kappa, cap, c.max_lateral_accel_mps2, clearance, c.clearance, stop, c.stop_decel_mps2
        )
        binds = False
        if clearance is not None:
            finite = np.isfinite(clearance)
            binds = bool(np.any(clearance_speed_limit_mps(clearance[finite], c.clearance) < cap - 1e-6))
        return limit, binds

    def _pedestrian_clearance(self, inp: SpeedInput, stations: np.ndarray) -> np.ndarray | None:
        """(L,) eq. (2)'s clearance c at each station (inf where no pedestrian is beside the body)."""
        c = self.config
        out = np.full(stations.shape, np.inf)
        seen = False
        offsets = self._path_offsets(inp)
        for o in inp.obstacles:
            if o.cls is not ObjectClass.PEDESTRIAN:
                continue
            ahead = self._rel(inp.front_s_m, o.s_m)
            if ahead < -self.body_length_m or ahead > stations[-1]:
                continue
            gap = abs(o.d_m - float(np.interp(ahead, *offsets))) - self.half_width_m - o.width_m / 2.0
            gap -= c.pedestrian_inflation_m
            # Beside the body: from the front reaching it to the rear leaving it.
            beside = (stations >= ahead - o.length_m / 2.0) & (stations <= ahead + self.body_length_m)
            out = np.where(beside, np.minimum(out, max(gap, 0.0)), out)
            seen = True
        return out if seen else None

    def _path_offsets(self, inp: SpeedInput) -> tuple[np.ndarray, np.ndarray]:
        """(distance ahead of the front, route offset d) of the planned path's points: a road user is
        in the way where it is near the path at its own station (a bay's path runs at the platform
        and then out to the lane; measured at the front alone, passengers on the platform ahead
        stood in the way of the merge)."""
        pts = inp.trajectory.points
        ahead = pts[:, 4] - inp.path_s_m - self.front_from_rear_m
        s = inp.front_s_m + ahead
        base = self.route.points_at(s)
        tangent = self.route.points_at(s + 0.5) - self.route.points_at(s - 0.5)
        heading = np.arctan2(tangent[:, 1], tangent[:, 0])
        d = -(pts[:, 0] - base[:, 0]) * np.sin(heading) + (pts[:, 1] - base[:, 1]) * np.cos(heading)
        return ahead, d

    def _occupancy(self, inp: SpeedInput) -> list[tuple[StObstacle, RouteObstacle]]:
        """Each road user's occupancy of the path over the horizon, at constant velocity."""
        c = self.config
        t = np.arange(0.0, c.st.horizon_s + 1e-9, 0.25)
        offsets = self._path_offsets(inp)
        path = Polyline(inp.trajectory.points[:, :2])
        out = []
        for o in inp.obstacles:
            ahead = self._rel(inp.front_s_m, o.s_m)
            if ahead > c.st.max_speed_mps * c.st.horizon_s + 10.0:
                continue
            if ahead - o.length_m / 2.0 < 0.0 and o.v_s_mps > STATIC_SPEED_MPS:
                # Alongside or behind the front and moving our way (a car overtaking while the
                # shuttle merges): not ours to stop for; once its rear is past the front it is a lead
                # (decision's in-path test skips it likewise). Clipped at the front, it read as a
                # wall there: a full-deceleration stop in the middle of a merge.
                continue
            # Slower than ``STATIC_SPEED_MPS`` is standing, as decision and the path planners take
            # it: a parked car's radar track creeps at 0.2 m/s, and over 4 s that walked it into
            # the path of a shuttle merging past it (a full-deceleration stop).
            # Vehicles keep their lane (Snow Lion: "a constant velocity model and a lane-keeping
            # speed planning scheme"; decision likewise predicts only the vulnerable sideways): an
            # oncoming car's 0.2 m/s of lateral track noise, followed for 5 s, put it head-on in the
            # shuttle's lane (a full-deceleration stop in snow). Pedestrians and cyclists cross.
            moving = o.speed_mps >= STATIC_SPEED_MPS
            s = ahead + (o.v_s_mps * t if moving else 0.0 * t)
            d = o.d_m + (o.v_d_mps * t if moving and o.cls.vulnerable else 0.0 * t)
            # Alongside the front already (its rear behind it), stopping changes nothing unless it
            # is in the body's own way: no corridor margin there (a car parked in S1's bay, its snow
            # track 0.1 m inside the margin, stopped the merge that passes it 0.4 m off).
            margin = c.corridor_margin_m if ahead - o.length_m / 2.0 > 0.0 else 0.0
            reach = self.half_width_m + o.width_m / 2.0 + margin
            if moving:
                inside = np.abs(d - np.interp(s, *offsets)) < reach
            else:
                # Standing: its distance to the path itself, as decision's in-path test measures it
                # (the route-frame offset put a car parked in S1's bay 0.1 m inside the corridor the
                # merge passes it by, and decision did not stop).
                inside = np.full(t.shape, abs(path.project(o.x_m, o.y_m).d_m) < reach)
            inside &= s + o.length_m / 2.0 > 0.0  # not behind the front
            idx = np.flatnonzero(inside)
            if len(idx) == 0:
                continue
            k = slice(int(idx[0]), int(idx[-1]) + 1)
            lo = np.maximum(s[k] - o.length_m / 2.0, 0.0)
            hi = np.maximum(s[k] + o.length_m / 2.0, lo)
            out.append((StObstacle(t_s=t[k], s_lo_m=lo, s_hi_m=hi), o))
        return out

    def _rel(self, from_s: float, to_s: float) -> float:
        return self.route.ds_m(from_s, to_s) if self.route.closed else to_s - from_s
