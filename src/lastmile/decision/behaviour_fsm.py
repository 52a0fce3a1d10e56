"""WATonoBus's decision state machine: six states, decisions made against the highest-risk obstacle.

States (paper Fig. 8): normal driving, intersection handling (all-way stop by arrival order,
pedestrians and cyclists first), pull-over to a dynamically chosen spot, passenger onboarding with the
door sensor and a dwell time, merging only when nothing approaches from the rear, and emergency stop,
reachable from every state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.geometry import SE2
from lastmile.core.objects import TrackedObjects
from lastmile.core.polyline import Polyline
from lastmile.core.predictions import PredictedPaths
from lastmile.core.route_obstacles import RouteObstacle, route_obstacles
from lastmile.core.safety_messages import FailSafeLevel, SafetyDirective
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState
from lastmile.decision.crosswalk_yield import crosswalk_yields
from lastmile.decision.decision_config import DecisionConfig, DecisionInput
from lastmile.decision.mission import MissionManager
from lastmile.decision.pullover_spot import SpotRequest, choose_spot
from lastmile.decision.right_of_way import ArrivalOrder, EntryLine
from lastmile.decision.traffic_light_rule import TrafficLightRule
from lastmile.decision.vehicle_cut_in import predicted_cut_ins
from lastmile.hdmap.layers import SLayerDatabase


@dataclass(slots=True)
class _Constraint:
    stop_front_s_m: float
    kind: str
    track_id: int = -1
    emergency_ok: bool = True


@dataclass
class BehaviourStateMachine:
    """The decision FSM; ``step`` runs once per planning cycle (10 Hz)."""

    layers: SLayerDatabase
    geometry: VehicleGeometry
    mission: MissionManager
    config: DecisionConfig = field(default_factory=DecisionConfig)
    state: BehaviourState = BehaviourState.NORMAL_DRIVING
    previous_state: BehaviourState = BehaviourState.NORMAL_DRIVING
    active_stop: int | None = None
    spot_front_s_m: float | None = None
    spot_committed: bool = False
    onboard_since_s: float | None = None
    doorway_clear_since_s: float | None = None
    door_closing: bool = False
    arrival: ArrivalOrder | None = None
    active_line: int | None = None
    line_stopped_since_s: float | None = None
    intersection_go: bool = False
    emergency_clear_since_s: float | None = None
    merge_from_s_m: float | None = None
    transitions: list[tuple[float, str, str, str]] = field(default_factory=list)
    _entries: dict[int, tuple[EntryLine, ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._route: Polyline = self.layers.centerline
        self.lights = TrafficLightRule(self.layers, self.config.traffic_lights)
        self._boxes: dict[int, np.ndarray] = {}
        for aws in self.layers.hdmap.all_way_stops:
            self._boxes[aws.id] = np.asarray(aws.conflict_polygon, dtype=float)
            lines = []
            for sl in self.layers.hdmap.stop_lines:
                if sl.all_way_stop_id != aws.id:
                    continue
                lanelet = self.layers.hdmap.lanelets[sl.lanelet_id]
                heading = lanelet.centerline.heading_at(lanelet.centerline.length_m - 0.1)
                mid = np.asarray(sl.line, dtype=float).mean(axis=0)
                lines.append(EntryLine(sl.id, float(mid[0]), float(mid[1]), heading))
            self._entries[aws.id] = tuple(lines)

    # ------------------------------------------------------------------------------------------------
    def step(self, inp: DecisionInput) -> BehaviourDecision:
        t_s = inp.stamp / 1e6
        g, c = self.geometry, self.config
        front_s = inp.route_s_m + g.front_from_rear_axle_m
        obstacles = route_obstacles(inp.tracks, self._route, inp.route_s_m, g.front_from_rear_axle_m)
        constraints: list[_Constraint] = []
        speed_cap = min(c.cruise_speed_mps, self.layers.speed_limit_at(front_s))
        door = False
        reason = "cruise"

        # The planned path, once per cycle: the corridor both obstacle checks sweep.
        path = Polyline(inp.trajectory.points[:, :2]) if inp.trajectory is not None else None
        constraints += self._in_path(obstacles, inp, front_s, path)
        constraints += self._cut_ins(obstacles, inp, front_s, path)
        constraints += self._crosswalks(inp.tracks, front_s, inp.speed_mps, inp.predictions)
        light_stop, light_why = self.lights.step(t_s, front_s, inp.speed_mps, inp.traffic_lights, self._ahead)
        if light_stop is not None:
            # Never an emergency stop for a light: a late red is braked for as hard as allowed, no harder.
            constraints.append(_Constraint(light_stop, light_why, emergency_ok=False))
        speed_cap = self._obey_safety(inp.safety, t_s, constraints, speed_cap)

        if self.state == BehaviourState.EMERGENCY_STOP:
            return self._emergency(inp, t_s, constraints, front_s)

        if self.state == BehaviourState.NORMAL_DRIVING:
            stop = self._next_requested_stop(front_s)
            line = self._next_stop_line(front_s)
            if line is not None and self._ahead(line[0], front_s) < c.intersection_approach_m:
                self._enter(BehaviourState.INTERSECTION, t_s, "approaching all-way stop")
                self.active_line = line[1]
            elif stop is not None:
                self._enter(BehaviourState.PULLOVER, t_s, f"stop {self.layers.stops[stop].stop.id} requested")
                self.active_stop = stop
                self.spot_front_s_m, self.spot_committed = None, False

        if self.state == BehaviourState.INTERSECTION:
            speed_cap, reason = self._intersection(inp, t_s, front_s, constraints, speed_cap)
        elif self.state == BehaviourState.PULLOVER:
            speed_cap, reason = self._pullover(inp, t_s, front_s, obstacles, constraints, speed_cap)
        elif self.state == BehaviourState.ONBOARDING:
            door, reason = self._onboarding(inp, t_s, constraints)
        elif self.state == BehaviourState.MERGING:
            speed_cap, reason = self._merging(inp, t_s, obstacles, constraints, speed_cap)

        binding = min(constraints, key=lambda k: k.stop_front_s_m, default=None)
        if binding is not None and binding.emergency_ok and self.state != BehaviourState.ONBOARDING:
            gap = binding.stop_front_s_m - front_s + c.min_gap_m - 0.5
            need = inp.speed_mps**2 / (2.0 * max(gap, 0.05))
            if need > c.emergency_decel_mps2 and inp.speed_mps > 0.5:
                self._enter(
                    BehaviourState.EMERGENCY_STOP, t_s, f"{binding.kind} {binding.track_id} too close"
                )
                return self._emergency(inp, t_s, constraints, front_s)
        if binding is not None and binding.kind not in ("spot",):
            reason = f"{reason}; stop for {binding.kind}"
        return BehaviourDecision(
            stamp=inp.stamp,
            state=self.state,
            speed_limit_mps=speed_cap,
            stop_at_s_m=None if binding is None else binding.stop_front_s_m,
            pullover_spot=self._spot_pose(),
            merge_from_s_m=self.merge_from_s_m,
            door_open=door,
            risk_track_id=-1 if binding is None else binding.track_id,
            reason=reason,
        )

    # --- shared checks ---------------------------------------------------------------------------
    def _in_path(
        self, obstacles: list[RouteObstacle], inp: DecisionInput, front_s: float, path: Polyline | None
    ) -> list[_Constraint]:
        """Obstacles in (or about to enter) the corridor swept along the planned path."""
        g, c = self.geometry, self.config
        out: list[_Constraint] = []
        for o in obstacles:
            if o.ds_m < -g.length_m or o.ds_m > 70.0:
                continue
            half = g.width_m / 2.0 + o.width_m / 2.0 + c.corridor_margin_m
            # Constant-velocity prediction over the time the shuttle needs to get there (Snow Lion).
            horizon = min(4.0, max(o.ds_m, 0.0) / max(inp.speed_mps, 1.0)) if o.cls.vulnerable else 0.0
            # Offset of the planned path from the route where the obstacle is (pull-over, nudge).
            path_d = o.d_m - path.project(o.x_m, o.y_m).d_m if path is not None else 0.0
            hit = any(abs(o.d_m + o.v_d_mps * horizon * k / 4.0 - path_d) < half for k in range(5))
            if not hit:
                continue
            if o.ds_m < -1.0 and o.v_s_mps > 0.0:
                continue  # behind the front, moving with us: not ours to stop for
            stop_s = _lead_stop_s_m(o.s_m, o.length_m, o.v_s_mps) - c.min_gap_m
            out.append(_Constraint(stop_s, o.cls.name.lower(), o.track_id))
        return out

    def _cut_ins(
        self, obstacles: list[RouteObstacle], inp: DecisionInput, front_s: float, path: Polyline | None
    ) -> list[_Constraint]:
        """Vehicles the lane-following prediction brings into the corridor ahead before the shuttle
        passes (``vehicle_cut_in``): followed like a lead from where they enter. Never an emergency
        stop on a prediction alone; once the car is in the corridor the in-path test takes over."""
        c = self.config
        cut_ins = predicted_cut_ins(
            obstacles,
            inp.predictions,
            self._route,
            path,
            front_s,
            inp.speed_mps,
            self.geometry.width_m / 2.0 + c.corridor_margin_m,
            horizon_s=c.vehicle_prediction_horizon_s,
            pass_margin_s=c.cut_in_pass_margin_s,
        )
        return [
            _Constraint(
                _lead_stop_s_m(k.entry_s_m, k.length_m, k.speed_along_mps) - c.min_gap_m,
                "cut-in",
                k.track_id,
                emergency_ok=False,
            )
            for k in cut_ins
        ]

    def _crosswalks(
        self,
        tracks: TrackedObjects,
        front_s: float,
        speed_mps: float,
        predictions: PredictedPaths | None = None,
    ) -> list[_Constraint]:
        """Yield at a crosswalk to the people ``crosswalk_yield`` finds there or about to be."""
        c = self.config
        return [
            _Constraint(stop_s, "crosswalk", tid, emergency_ok=False)
            for stop_s, tid in crosswalk_yields(
                self.layers.crosswalks,
                self._route,
                tracks,
                front_s,
                speed_mps,
                self.geometry.length_m,
                predictions,
                margin_m=c.crosswalk_margin_m,
                lookahead_s=c.crosswalk_lookahead_s,
            )
        ]

    # --- states ---------------------------------------------------------------------------------
    def _intersection(
        self, inp: DecisionInput, t_s: float, front_s: float, constraints: list[_Constraint], cap: float
    ) -> tuple[float, str]:
        rl = self.layers.stop_lines[self.active_line] if self.active_line is not None else None
        if rl is None:
            self._enter(BehaviourState.NORMAL_DRIVING, t_s, "no stop line")
            return cap, "cruise"
        aws_id = rl.all_way_stop_id
        if aws_id is None or aws_id not in self._boxes:
            self._enter(BehaviourState.NORMAL_DRIVING, t_s, "stop line without an all-way stop")
            return cap, "cruise"
        if self.arrival is None or self.arrival.box is not self._boxes[aws_id]:
            entries = tuple(e for e in self._entries[aws_id] if e.stop_line_id != rl.stop_line.id)
            self.arrival = ArrivalOrder(entries=entries, box=self._boxes[aws_id])
        self.arrival.observe(t_s, inp.tracks)
        to_line = self._ahead(rl.s_m, front_s)
        if self.intersection_go:
            if to_line < -15.0:
                self._leave_intersection(t_s)
                return cap, "cleared intersection"
            return cap, "crossing intersection"
        if to_line < 3.0 and inp.speed_mps < 0.1:
            self.arrival.ego_stopped(t_s)
            if self.line_stopped_since_s is None:
                self.line_stopped_since_s = t_s
        owed = self.arrival.owed()
        inside = self.arrival.box_occupied(inp.tracks)
        stood = (
            self.line_stopped_since_s is not None
            and t_s - self.line_stopped_since_s >= self.config.full_stop_s
        )
        if stood and not owed and inside < 0:
            self.intersection_go = True
            return cap, "right of way: go"
        constraints.append(
            _Constraint(
                rl.s_m - 0.5, "stop_line", inside if inside >= 0 else (owed[0] if owed else -1), False
            )
        )
        why = (
            f"yield to {len(owed)} earlier arrivals"
            if owed
            else ("box occupied" if inside >= 0 else "full stop")
        )
        return cap, why

    def _leave_intersection(self, t_s: float) -> None:
        self.intersection_go = False
        self.line_stopped_since_s = None
        self.active_line = None
        if self.arrival is not None:
            self.arrival.reset()
        self._enter(BehaviourState.NORMAL_DRIVING, t_s, "intersection cleared")

    def _pullover(
        self,
        inp: DecisionInput,
        t_s: float,
        front_s: float,
        obstacles: list[RouteObstacle],
        constraints: list[_Constraint],
        cap: float,
    ) -> tuple[float, str]:
        assert self.active_stop is not None
        rs = self.layers.stops[self.active_stop]
        c, g = self.config, self.geometry
        lane_right = float(self.layers.lane_right_at(rs.s_start_m + 1.0))
        if not self.spot_committed:
            # The spot is chosen anew every cycle from what the 20 m scan sees (WATonoBus, Sec. bus-stop
            # handling): a car parked further along the bay only shows up as the shuttle nears it.
            stopping_m = inp.speed_mps**2 / (2.0 * 1.0)
            request = SpotRequest(
                platform_start_s_m=rs.s_start_m,
                platform_end_s_m=rs.s_end_m,
                bay_edge_d_m=lane_right,
                curb_d_m=rs.curb_d_m,
                vehicle_length_m=g.length_m,
                transition_m=c.transition_m * 0.5,
                margin_m=c.min_gap_m + 0.5,
                preferred_front_s_m=0.5 * (rs.s_start_m + rs.s_end_m) + g.length_m / 2.0,
                exit_m=c.merge_room_m,
                earliest_front_s_m=front_s + stopping_m if self.spot_front_s_m is not None else -math.inf,
            )
            seen = [o for o in obstacles if o.ds_m < c.spot_scan_m + o.length_m]
            spot = choose_spot(request, seen)
            if spot is not None or self.spot_front_s_m is None:
                self.spot_front_s_m = spot
            # Committed once the spot is within the scan with room to spare: it no longer moves.
            if (
                self.spot_front_s_m is not None
                and self._ahead(self.spot_front_s_m + c.merge_room_m, front_s) < 20.0
            ):
                self.spot_committed = True
        if self.spot_front_s_m is None:
            if self._ahead(rs.s_end_m, front_s) < 0.0:
                self._finish_stop(t_s, "stop blocked: no free spot")
            return cap, "stop blocked: no free spot, passing"
        constraints.append(_Constraint(self.spot_front_s_m, "spot", -1, False))
        arrived = abs(self.spot_front_s_m - front_s) < 0.6 and inp.speed_mps < 0.05
        if arrived:
            self._enter(BehaviourState.ONBOARDING, t_s, "at pull-over spot")
            self.onboard_since_s = None
            self.doorway_clear_since_s = None
            self.door_closing = False
        if self._ahead(self.spot_front_s_m, front_s) < c.stop_approach_m:
            cap = min(cap, c.pullover_speed_mps)
        return cap, "pulling over"

    def _onboarding(self, inp: DecisionInput, t_s: float, constraints: list[_Constraint]) -> tuple[bool, str]:
        c = self.config
        front_s = inp.route_s_m + self.geometry.front_from_rear_axle_m
        constraints.append(_Constraint(front_s, "onboarding", -1, False))
        if self.door_closing:
            if not inp.door_open:
                rs = self.layers.stops[self.active_stop] if self.active_stop is not None else None
                if rs is not None:
                    self.mission.served(rs.stop.id)
                self._enter(BehaviourState.MERGING, t_s, "door closed")
                self.merge_from_s_m = inp.route_s_m
            return False, "closing door"
        if inp.door_open and self.onboard_since_s is None:
            self.onboard_since_s = t_s
        if inp.person_in_doorway or not inp.door_open:
            self.doorway_clear_since_s = None
        elif self.doorway_clear_since_s is None:
            self.doorway_clear_since_s = t_s
        if (
            self.onboard_since_s is not None
            and t_s - self.onboard_since_s >= c.dwell_min_s
            and self.doorway_clear_since_s is not None
            and t_s - self.doorway_clear_since_s >= c.doorway_clear_s
        ):
            self.door_closing = True
            return False, "closing door"
        return True, "passengers boarding"

    def _merging(
        self,
        inp: DecisionInput,
        t_s: float,
        obstacles: list[RouteObstacle],
        constraints: list[_Constraint],
        cap: float,
    ) -> tuple[float, str]:
        c, g = self.config, self.geometry
        front_s = inp.route_s_m + g.front_from_rear_axle_m
        if (
            abs(inp.route_d_m) < 0.3
            and self.merge_from_s_m is not None
            and inp.route_s_m - self.merge_from_s_m > 5.0
        ):
            self._finish_stop(t_s, "merged")
            return cap, "merged"
        blocker = self._rear_blocker(obstacles)
        if blocker >= 0 and (self.merge_from_s_m is None or inp.route_s_m - self.merge_from_s_m < 2.0):
            constraints.append(_Constraint(front_s, "rear_traffic", blocker, False))
            self.merge_from_s_m = inp.route_s_m
            return min(cap, c.merge_speed_mps), "waiting: traffic from the rear"
        return min(cap, c.merge_speed_mps), "merging"

    def _rear_blocker(self, obstacles: list[RouteObstacle]) -> int:
        c, g = self.config, self.geometry
        for o in obstacles:
            behind = -(o.ds_m + g.length_m)  # distance from our rear bumper back to the object
            if behind < -g.length_m or behind > c.rear_check_m or abs(o.d_m) > 2.5:
                continue
            if behind < 8.0:
                return o.track_id
            if o.v_s_mps > 0.5 and behind / o.v_s_mps < c.rear_tta_s:
                return o.track_id
        return -1

    def _finish_stop(self, t_s: float, why: str) -> None:
        self.active_stop = None
        self.spot_front_s_m = None
        self.spot_committed = False
        self.merge_from_s_m = None
        self._enter(BehaviourState.NORMAL_DRIVING, t_s, why)

    def _emergency(
        self, inp: DecisionInput, t_s: float, constraints: list[_Constraint], front_s: float
    ) -> BehaviourDecision:
        c = self.config
        close = [k for k in constraints if k.emergency_ok and k.stop_front_s_m - front_s < c.min_gap_m + 2.0]
        ordered = inp.safety is not None and inp.safety.emergency_stop
        # An e-stop the safety module ordered holds until the fail-safe releases it (operator reset).
        if inp.speed_mps < 0.05 and not close and not ordered:
            if self.emergency_clear_since_s is None:
                self.emergency_clear_since_s = t_s
            elif t_s - self.emergency_clear_since_s > 1.0:
                self.emergency_clear_since_s = None
                back = self.previous_state
                self._enter(back, t_s, "emergency cleared")
        else:
            self.emergency_clear_since_s = None
        # Hold still for this cycle even when just cleared; the next cycle plans from the restored state.
        return BehaviourDecision(
            stamp=inp.stamp,
            state=self.state,
            speed_limit_mps=0.0,
            stop_at_s_m=front_s,
            pullover_spot=self._spot_pose(),
            merge_from_s_m=self.merge_from_s_m,
            door_open=False,
            risk_track_id=close[0].track_id if close else -1,
            reason="emergency stop",
        )

    def _obey_safety(
        self, sd: SafetyDirective | None, t_s: float, constraints: list[_Constraint], cap: float
    ) -> float:
        """The fail-safe's directive: a speed cap, a stop point for the minimal risk manoeuvre, an e-stop."""
        if sd is None or sd.level == FailSafeLevel.NONE:
            return cap
        if sd.emergency_stop:
            self.request_emergency(t_s, "safety: " + "; ".join(sd.reasons))
        if sd.speed_cap_mps is not None:
            cap = min(cap, sd.speed_cap_mps)
        if sd.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE and sd.mrm_stop_s_m is not None:
            # A comfortable stop at the arbiter's point (never an emergency brake for it).
            constraints.append(_Constraint(sd.mrm_stop_s_m, "minimal risk manoeuvre", emergency_ok=False))
        return cap

    def request_emergency(self, t_s: float, why: str) -> None:
        """The e-stop button or a safety monitor: every state can reach emergency stop."""
        if self.state != BehaviourState.EMERGENCY_STOP:
            self._enter(BehaviourState.EMERGENCY_STOP, t_s, why)

    # --- helpers --------------------------------------------------------------------------------
    def _enter(self, state: BehaviourState, t_s: float, why: str) -> None:
        if state == self.state:
            return
        if state == BehaviourState.EMERGENCY_STOP:
            self.previous_state = self.state
        self.transitions.append((t_s, self.state.value, state.value, why))
        self.state = state

    def _ahead(self, s_m: float, front_s: float) -> float:
        return self._route.ds_m(front_s, s_m)

    def _next_requested_stop(self, front_s: float) -> int | None:
        for i, rs in enumerate(self.layers.stops):
            ahead = self._ahead(rs.s_start_m, front_s)
            if 0.0 < ahead < self.config.stop_approach_m and self.mission.wants(rs.stop.id):
                return i
        return None

    def _next_stop_line(self, front_s: float) -> tuple[float, int] | None:
        best: tuple[float, int] | None = None
        for i, rl in enumerate(self.layers.stop_lines):
            if rl.all_way_stop_id is None:
                continue
            ahead = self._ahead(rl.s_m, front_s)
            if ahead > -0.5 and (best is None or ahead < self._ahead(best[0], front_s)):
                best = (rl.s_m, i)
        return best

    def _spot_pose(self) -> SE2 | None:
        if self.spot_front_s_m is None or self.active_stop is None:
            return None
        rs = self.layers.stops[self.active_stop]
        rear_s = self.spot_front_s_m - self.geometry.front_from_rear_axle_m
        x, y, yaw = self._route.point_at(rear_s)
        d = self.spot_d_m(rs.curb_d_m)
        return SE2(x - d * math.sin(yaw), y + d * math.cos(yaw), yaw)

    def spot_d_m(self, curb_d_m: float) -> float:
        """Route d of the shuttle's centre line when pulled over (curb gap target kept)."""
        return curb_d_m + self.config.curb_gap_target_m + self.geometry.width_m / 2.0


LEAD_DECEL_MPS2 = 3.0
"""How hard a lead is assumed to brake when it stops (where its stop point is taken to be)."""


def _lead_stop_s_m(s_m: float, length_m: float, speed_along_mps: float) -> float:
    """Route s of the rear of a lead at ``s_m`` once it has stopped: a lead moving along the route
    stops where it would stop, and eq. (2) applies to that point (one coming towards the shuttle, or
    crossing, is taken as standing)."""
    moving_away = max(speed_along_mps, 0.0)
    return s_m - length_m / 2.0 + moving_away**2 / (2.0 * LEAD_DECEL_MPS2)
