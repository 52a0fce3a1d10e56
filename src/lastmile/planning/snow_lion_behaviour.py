"""Snow Lion's behaviour planner: scenario-tagged offset candidates, d_t = argmin(J_s + J_d + J_o + J_dyn).

Each planning cycle (Snow Lion, "Behavioral Planning"):

- the route's **scenario tag** where the shuttle is (:mod:`lastmile.planning.scenario_tags`: common road,
  parking lot, unprotected intersection) picks the **offset candidates** D, the static obstacles'
  **width inflation** w_o and the **reference speed** v_r (:class:`BehaviourConfig`);
- every candidate d is a quintic move from the offset the shuttle is planned at now (d_0) to d, held;
  sampled over ``s_max_m`` it is scored by J_s = w_s (1 - s_m(d) / s_max) (s_m: how far it runs before
  its body meets an inflated static obstacle), J_d = w_d1 |d - d_0| + w_d2 |d|, J_o = w_o1 / c_avg +
  w_o2 / c_min (clearances to the static obstacles beside it) and J_dyn (a high cost when it meets a
  moving road user's constant-velocity path, less the later it would);
- the **1/f_p guard against serpentine motion**: the kept target is replaced only by a candidate that
  has been the cheapest, by ``switch_margin`` of the kept cost, for ``switch_delay_s``, unless the
  kept one has become blocked sooner or collision-prone (then at once);
- the **truncation flag** pi_s: when the path chosen meets a static obstacle, the reference route is
  truncated there and the shuttle stops ``stop_gap_m`` before its end (``Trajectory.truncated``,
  ``stop_at_route_s_m``);
- **observation areas** at unprotected intersections: within ``observation.approach_m`` of the stop line
  and through the junction the speed is held to that scenario's v_r, and a moving road user in the
  area whose constant-velocity path enters the shuttle's lane inside the junction stops the shuttle at
  the stop line (a lane stop) until none has been seen for ``observation.clear_s``.

A pass of a stationary obstacle through the adjacent lane, which decision orders
(``BehaviourDecision.pass_request``), and the pull-over, onboarding and merge paths are the offset-pass
planner's (:class:`~lastmile.planning.pass_path.OffsetPassPlanner`, which this one extends).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lastmile.core.geometry import FloatArray
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, Trajectory
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.planning.behaviour_config import BehaviourConfig, ScenarioProfile
from lastmile.planning.local_path import CurbLookup, LocalPathConfig
from lastmile.planning.pass_path import OffsetPassPlanner, _smoothstep5
from lastmile.planning.road_edge import BodyPlacement, DrivableLookup
from lastmile.planning.scenario_tags import ScenarioTag, TaggedStretch, route_scenario_tags, stretches

STATIC_SPEED_MPS = 0.5
"""Road users slower than this are static obstacles (the potential field's ``max_speed_mps``)."""
LANE_EDGE_MARGIN_M = 0.1
"""A candidate's body stays this far inside the lane (the potential field's bound)."""
APPROACH_DECEL_MPS2 = 1.0
"""The deceleration a lower reference speed ahead is approached with (inside Snow Lion's envelope)."""
COMFORT_STOP_DECEL_MPS2 = 1.8
"""A lane stop needing more than this is not ordered: the shuttle is already committed (the
longitudinal law's ``comfort_decel_mps2``)."""


@dataclass(frozen=True, slots=True)
class CandidateCost:
    """One candidate's cost terms (inf: leaves the lane)."""

    offset_m: float
    j_s: float
    j_d: float
    j_o: float
    j_dyn: float
    free_m: float
    """s_m(d): how far the candidate runs before it meets an inflated static obstacle (s_max: never)."""

    @property
    def total(self) -> float:
        return self.j_s + self.j_d + self.j_o + self.j_dyn


@dataclass(frozen=True, slots=True)
class _Move:
    """A quintic from ``from_d_m`` at route s ``start_s_m`` (unwrapped) to ``to_d_m`` over ``length_m``."""

    start_s_m: float
    from_d_m: float
    to_d_m: float
    length_m: float

    def at(self, s_m: FloatArray) -> FloatArray:
        u = np.clip((np.asarray(s_m, dtype=float) - self.start_s_m) / self.length_m, 0.0, 1.0)
        return self.from_d_m + (self.to_d_m - self.from_d_m) * _smoothstep5(u)


class SnowLionBehaviourPlanner(OffsetPassPlanner):
    """The behaviour planner (see the module docstring); ``layers`` gives the tags and lane widths."""

    def __init__(
        self,
        route: Polyline,
        half_width_m: float,
        config: LocalPathConfig | None = None,
        curb_right_d_m: CurbLookup | None = None,
        body_behind_m: float = 0.0,
        body_ahead_m: float = 0.0,
        drivable: DrivableLookup | None = None,
        max_curvature_1pm: float = 0.2,
        layers: SLayerDatabase | None = None,
        body: BodyPlacement | None = None,
    ) -> None:
        super().__init__(
            route,
            half_width_m,
            config,
            curb_right_d_m,
            body_behind_m,
            body_ahead_m,
            drivable,
            max_curvature_1pm,
            body,
        )
        self.behaviour: BehaviourConfig = self.config.behaviour or BehaviourConfig()
        self.layers = layers
        b = self.behaviour
        if layers is not None:
            self.tags = route_scenario_tags(layers, b.parking_margin_m, b.parking_lanelet_ids)
            self.stretches: tuple[TaggedStretch, ...] = stretches(self.tags, layers.s_m, layers.step_m)
        else:
            self.tags = np.zeros(1, dtype=np.int8)
            self.stretches = ()
        self._move: _Move | None = None
        self._pending: tuple[float, float] | None = None  # (offset, since s)
        self._now_s = 0.0
        self._ego_s = 0.0
        self._ego_speed_mps = 0.0
        self._last: tuple[float, float] | None = None  # (t, ego s) of the previous cycle
        self._last_conflict_s = -math.inf
        self.last_costs: list[CandidateCost] = []
        self.truncated_at_s_m: float | None = None

    # --- the planning cycle -----------------------------------------------------------------------
    def plan(
        self,
        stamp: Stamp,
        ego_s_m: float,
        ego_d_m: float,
        decision: BehaviourDecision,
        obstacles: list[RouteObstacle],
    ) -> Trajectory:
        self._now_s = int(stamp) / 1e6
        self._track_speed(ego_s_m)
        self._ego_s = ego_s_m
        self.truncated_at_s_m = None
        trajectory = super().plan(stamp, ego_s_m, ego_d_m, decision, obstacles)
        front = ego_s_m + self.body_ahead_m
        stop = None
        if self.truncated_at_s_m is not None:
            stop = self.truncated_at_s_m + self.body_ahead_m - self.behaviour.stop_gap_m
        observe_stop, limit = self._observation(front, obstacles, decision)
        if observe_stop is not None and (stop is None or observe_stop < stop):
            stop = observe_stop
        return dataclasses.replace(
            trajectory,
            speed_limit_mps=min(limit, self._scenario_limit_mps(front)),
            stop_at_route_s_m=self._wrap(stop) if stop is not None else None,
            truncated=self.truncated_at_s_m is not None,
        )

    def offsets_m(
        self, s_m: FloatArray, decision: BehaviourDecision, obstacles: list[RouteObstacle], ego_d_m: float
    ) -> FloatArray:
        ego_s = self._ego_s
        driving = decision.state in (BehaviourState.NORMAL_DRIVING, BehaviourState.INTERSECTION)
        if not driving or decision.pass_request is not None:
            # Pull-over, merge and passes are the offset-pass planner's; afterwards the behaviour
            # planner starts again from where that path leaves the shuttle.
            d = super().offsets_m(s_m, decision, obstacles, ego_d_m)
            here = float(np.interp(ego_s, s_m, d))
            self._move = _Move(ego_s, here, here, 1.0)
            self._pending = None
            if driving and self.chosen is None:
                self._truncate(
                    ego_s, lambda g: np.interp(g, s_m, d).astype(np.float64), obstacles, self._profile(ego_s)
                )
            return d
        move = self._choose_target(ego_s, obstacles)
        self._truncate(ego_s, move.at, obstacles, self._profile(ego_s))
        return move.at(s_m)

    # --- the candidates ---------------------------------------------------------------------------
    def _profile(self, s_m: float) -> ScenarioProfile:
        return self._profile_of(self._tag(s_m))

    def _profile_of(self, tag: ScenarioTag) -> ScenarioProfile:
        b = self.behaviour
        if tag is ScenarioTag.PARKING_LOT:
            return b.parking_lot
        if tag is ScenarioTag.UNPROTECTED_INTERSECTION:
            return b.unprotected_intersection
        return b.common_road

    def _tag(self, s_m: float) -> ScenarioTag:
        if self.layers is None:
            return ScenarioTag.COMMON_ROAD
        return ScenarioTag(int(self.tags[self.layers.record_index(s_m)]))

    def _current_move(self, ego_s: float) -> _Move:
        move = self._move
        if move is None:
            return _Move(ego_s, 0.0, 0.0, 1.0)
        if self.route.closed and move.start_s_m - ego_s > self.route.length_m / 2.0:
            move = dataclasses.replace(move, start_s_m=move.start_s_m - self.route.length_m)  # a new lap
        return move

    def _choose_target(self, ego_s: float, obstacles: list[RouteObstacle]) -> _Move:
        """The move to the target offset, with the 1/f_p guard against serpentine motion."""
        b = self.behaviour
        kept = self._current_move(ego_s)
        d_now = float(kept.at(np.array([ego_s]))[0])
        profile = self._profile(ego_s)
        offsets = sorted({*profile.offsets_m, *self._clearing_offsets(ego_s, obstacles, profile)})
        moves = {d: self._move_to(ego_s, d_now, d) for d in offsets}
        moves[kept.to_d_m] = kept  # the kept target is scored along the move it is on
        costs = {d: self.candidate_cost(ego_s, d_now, m, obstacles, profile) for d, m in moves.items()}
        self.last_costs = list(costs.values())
        best = min(costs, key=lambda d: (costs[d].total, abs(d)))
        keep = costs[kept.to_d_m]
        choice = kept.to_d_m
        if best != kept.to_d_m:
            worse = costs[best]
            urgent = (
                not math.isfinite(keep.total)
                or keep.free_m < worse.free_m - 1e-9
                or keep.j_dyn > worse.j_dyn + 1e-9
            )
            cheaper = worse.total < keep.total - b.switch_margin * abs(keep.total)
            if urgent:
                choice = best
            elif cheaper:
                if self._pending is None or self._pending[0] != best:
                    self._pending = (best, self._now_s)
                if self._now_s - self._pending[1] >= b.switch_delay_s - 1e-9:
                    choice = best
            else:
                self._pending = None
        else:
            self._pending = None
        if choice != kept.to_d_m:
            self._pending = None
            self._move = moves[choice]
        else:
            self._move = kept
        return self._move

    def _move_to(self, ego_s: float, d_now: float, d: float) -> _Move:
        length = max(self.comfortable_length_m(abs(d - d_now)), 2.0) if abs(d - d_now) > 1e-9 else 1.0
        return _Move(ego_s, d_now, d, length)

    def _clearing_offsets(
        self, ego_s: float, obstacles: list[RouteObstacle], profile: ScenarioProfile
    ) -> list[float]:
        """The least offset that clears each static obstacle partly in the lane (besides the fixed
        candidates: the potential field reaches any offset, a grid alone would stop for some)."""
        if len(profile.offsets_m) == 1:
            return []  # no lateral moves in this scenario
        out = []
        w, hw = profile.inflation_m, self.half_width_m
        for o in obstacles:
            if o.speed_mps >= STATIC_SPEED_MPS:
                continue
            ahead = self._rel(ego_s, o.s_m)
            if not (0.0 < ahead < self.behaviour.s_max_m):
                continue
            if o.d_m < 0.0:
                out.append(o.d_m + o.width_m / 2.0 + w + hw + 0.05)
            else:
                out.append(o.d_m - o.width_m / 2.0 - w - hw - 0.05)
        lo, hi = min(profile.offsets_m), max(profile.offsets_m)
        return [round(d, 2) for d in out if lo - 1e-9 <= d <= hi + 1e-9]

    def candidate_cost(
        self,
        ego_s: float,
        d_now: float,
        move: _Move,
        obstacles: list[RouteObstacle],
        profile: ScenarioProfile,
    ) -> CandidateCost:
        """J_s, J_d, J_o and J_dyn of the path ``move`` draws from the rear axle on."""
        b = self.behaviour
        g = np.arange(0.0, b.s_max_m + 1e-9, b.step_m)  # rear-axle stations ahead of the shuttle
        d = move.at(ego_s + g)
        target = move.to_d_m
        j_d = b.w_d1 * abs(target - d_now) + b.w_d2 * abs(target)
        if not self._inside_lane(ego_s + g, d, target):
            return CandidateCost(target, math.inf, j_d, 0.0, 0.0, 0.0)
        free_m, c_avg, c_min = self._static(g, d, ego_s, obstacles, profile.inflation_m)
        j_s = b.w_s * (1.0 - free_m / b.s_max_m)
        j_o = 0.0
        if math.isfinite(c_min):
            j_o = b.w_o1 / max(c_avg, 0.05) + b.w_o2 / max(c_min, 0.05)
        j_dyn = self._dynamic(g, d, ego_s, obstacles, profile.inflation_m)
        return CandidateCost(target, j_s, j_d, j_o, j_dyn, free_m)

    def _inside_lane(self, s_m: FloatArray, d_m: FloatArray, target_m: float) -> bool:
        if self.layers is None or abs(target_m) < 1e-9:
            return True  # the route's centre line is the lane's
        idx = self.layers.record_indices(s_m)
        left = self.layers.lane_left_d_m[idx] - LANE_EDGE_MARGIN_M
        right = self.layers.lane_right_d_m[idx] + LANE_EDGE_MARGIN_M
        hw = self.half_width_m
        return bool(np.all(d_m + hw <= np.maximum(left, hw)) and np.all(d_m - hw >= np.minimum(right, -hw)))

    def _static(
        self, g: FloatArray, d: FloatArray, ego_s: float, obstacles: list[RouteObstacle], inflation_m: float
    ) -> tuple[float, float, float]:
        """(s_m(d), c_avg, c_min): the free run before the body meets an inflated static obstacle and
        the average and least clearance to the real ones beside it up to there (inf: none beside)."""
        boxes = self._static_boxes(ego_s, obstacles, inflation_m)
        if len(boxes) == 0:
            return self.behaviour.s_max_m, math.inf, math.inf
        lo_s, hi_s, lo_d, hi_d = (boxes[:, k][None, :] for k in range(4))
        beside = (g[:, None] + self.body_ahead_m > lo_s) & (g[:, None] - self.body_behind_m < hi_s)
        gap = np.maximum(lo_d - (d[:, None] + self.half_width_m), (d[:, None] - self.half_width_m) - hi_d)
        hit = np.flatnonzero(np.any(beside & (gap < 0.0), axis=1))
        free = float(g[hit[0]]) if len(hit) else self.behaviour.s_max_m
        upto = g <= free
        clear = np.where(beside, gap + inflation_m, np.inf).min(axis=1)[upto]
        clear = np.minimum(clear[np.isfinite(clear)], self.behaviour.clearance_cap_m)
        if len(clear) == 0:
            return free, math.inf, math.inf
        return free, float(clear.mean()), float(clear.min())

    def _static_boxes(self, ego_s: float, obstacles: list[RouteObstacle], w: float) -> FloatArray:
        """(K, 4) inflated footprints (s from the rear axle, d) of the static obstacles ahead."""
        rows = []
        for o in obstacles:
            if o.speed_mps >= STATIC_SPEED_MPS:
                continue
            s = self._rel(ego_s, o.s_m)
            if (
                s + o.length_m / 2.0 < -self.body_behind_m
                or s - o.length_m / 2.0 > self.behaviour.s_max_m + 10
            ):
                continue
            half_l, half_w = o.length_m / 2.0 + w, o.width_m / 2.0 + w
            rows.append((s - half_l, s + half_l, o.d_m - half_w, o.d_m + half_w))
        return np.asarray(rows, dtype=float).reshape(-1, 4)

    def _dynamic(
        self, g: FloatArray, d: FloatArray, ego_s: float, obstacles: list[RouteObstacle], inflation_m: float
    ) -> float:
        """J_dyn: w_dyn (1 - t / T) at the earliest time t the candidate's body meets a moving road
        user's inflated footprint, each at constant velocity (0: it meets none within T)."""
        b = self.behaviour
        speed = max(self._ego_speed_mps, b.min_planning_speed_mps)
        t = g / speed
        within = t <= b.dynamic_horizon_s
        g, d, t = g[within], d[within], t[within]
        worst = 0.0
        for o in obstacles:
            if o.speed_mps < STATIC_SPEED_MPS:
                continue
            s = self._rel(ego_s, o.s_m) + o.v_s_mps * t
            od = o.d_m + o.v_d_mps * t
            half_l, half_w = o.length_m / 2.0 + inflation_m, o.width_m / 2.0 + inflation_m
            meet_s = (g + self.body_ahead_m > s - half_l) & (g - self.body_behind_m < s + half_l)
            meet_d = np.abs(od - d) < half_w + self.half_width_m
            hit = np.flatnonzero(meet_s & meet_d)
            if len(hit):
                worst = max(worst, b.w_dyn * (1.0 - float(t[hit[0]]) / b.dynamic_horizon_s))
        return worst

    def _truncate(
        self,
        ego_s: float,
        offsets: Callable[[FloatArray], FloatArray],
        obstacles: list[RouteObstacle],
        profile: ScenarioProfile,
    ) -> None:
        """pi_s: the route s (rear axle) where the planned path first meets an inflated static obstacle."""
        b = self.behaviour
        g = np.arange(0.0, b.s_max_m + 1e-9, b.step_m)
        d = np.asarray(offsets(ego_s + g), dtype=np.float64)
        free, _, _ = self._static(g, d, ego_s, obstacles, profile.inflation_m)
        if free < b.s_max_m:
            self.truncated_at_s_m = ego_s + free

    # --- speed: scenario reference speeds, observation areas ----------------------------------------
    def _scenario_limit_mps(self, front_s: float) -> float:
        """v_r where the front is, and the lower ones ahead approached at ``APPROACH_DECEL_MPS2``."""
        limit = self._profile(front_s).reference_speed_mps or math.inf
        for st in self.stretches:
            v = self._profile_of(st.tag).reference_speed_mps
            if v is None:
                continue
            start = st.start_s_m
            if st.tag is ScenarioTag.UNPROTECTED_INTERSECTION:
                start -= self.behaviour.observation.approach_m + self.behaviour.observation.stop_back_m
            ahead = self._rel(front_s, start)
            inside = ahead <= 0.0 and self._rel(front_s, st.end_s_m) > 0.0
            if inside:
                limit = min(limit, v)
            elif 0.0 < ahead < 60.0:
                limit = min(limit, math.sqrt(v * v + 2.0 * APPROACH_DECEL_MPS2 * ahead))
        return limit

    def _observation(
        self, front_s: float, obstacles: list[RouteObstacle], decision: BehaviourDecision
    ) -> tuple[float | None, float]:
        """(the stop line's route s when a watched road user conflicts, else None; a speed cap)."""
        oc = self.behaviour.observation
        if decision.state not in (BehaviourState.NORMAL_DRIVING, BehaviourState.INTERSECTION):
            return None, math.inf
        for st in self.stretches:
            if st.tag is not ScenarioTag.UNPROTECTED_INTERSECTION:
                continue
            line = st.start_s_m - oc.stop_back_m
            to_line = self._rel(front_s, line)
            if not (-0.5 <= to_line <= oc.approach_m + 40.0):
                continue
            if self._conflict(front_s, st, obstacles):
                self._last_conflict_s = self._now_s
            recent = self._now_s - self._last_conflict_s <= oc.clear_s + 1e-9
            can_stop = to_line >= self._ego_speed_mps**2 / (2.0 * COMFORT_STOP_DECEL_MPS2)
            if recent and (can_stop or self._ego_speed_mps < 0.1):
                return self._unwrapped(front_s, line), math.inf
        return None, math.inf

    def _conflict(self, front_s: float, st: TaggedStretch, obstacles: list[RouteObstacle]) -> bool:
        """A moving road user within ``radius_m`` of the junction's middle whose constant-velocity path
        enters the shuttle's lane (widened by ``corridor_margin_m``) inside the junction."""
        oc = self.behaviour.observation
        mid = 0.5 * (st.start_s_m + st.end_s_m)
        mx, my, _ = self.route.point_at(mid)
        t = np.arange(0.0, oc.horizon_s + 1e-9, 0.25)
        left, right = self._lane_at(mid)
        for o in obstacles:
            if o.speed_mps < oc.min_speed_mps or math.hypot(o.x_m - mx, o.y_m - my) > oc.radius_m:
                continue
            if right < o.d_m < left and o.v_s_mps > oc.min_speed_mps and abs(o.v_d_mps) < oc.min_speed_mps:
                continue  # travelling in the shuttle's lane with it: followed, not yielded to
            rel = self._rel(mid, o.s_m) + o.v_s_mps * t
            d = o.d_m + o.v_d_mps * t
            half = 0.5 * (st.end_s_m - st.start_s_m) + 1.0 + o.length_m / 2.0
            pad = oc.corridor_margin_m + o.width_m / 2.0
            if np.any((np.abs(rel) < half) & (d < left + pad) & (d > right - pad)):
                return True
        return False

    def _lane_at(self, s_m: float) -> tuple[float, float]:
        if self.layers is None:
            return self.config.lane_half_width_m, -self.config.lane_half_width_m
        i = self.layers.record_index(s_m)
        return float(self.layers.lane_left_d_m[i]), float(self.layers.lane_right_d_m[i])

    # --- helpers -----------------------------------------------------------------------------------
    def _track_speed(self, ego_s: float) -> None:
        """The shuttle's speed along the route from successive cycles (the planner's timing only)."""
        if self._last is not None:
            dt = self._now_s - self._last[0]
            if dt > 1e-6:
                v = max(self._rel(self._last[1], ego_s), 0.0) / dt
                self._ego_speed_mps = 0.5 * self._ego_speed_mps + 0.5 * v
        self._last = (self._now_s, ego_s)

    def _rel(self, from_s: float, to_s: float) -> float:
        return self.route.ds_m(from_s, to_s) if self.route.closed else to_s - from_s

    def _unwrapped(self, near_s: float, s: float) -> float:
        return near_s + self._rel(near_s, s)

    def _wrap(self, s: float) -> float:
        return s % self.route.length_m if self.route.closed else s
