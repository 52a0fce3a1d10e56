"""WATonoBus's decision state machine: six states, decisions made against the highest-risk obstacle.

States (paper Fig. 8): normal driving, intersection handling (all-way stop by arrival order,
pedestrians and cyclists first), pull-over to a dynamically chosen spot, passenger onboarding with the
door sensor and a dwell time, merging only when nothing approaches from the rear, and emergency stop,
reachable from every state. Each state has one handler (``_HANDLERS``); what persists between cycles
is one :class:`~lastmile.decision.behaviour_memory.BehaviourMemory`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.geometry import SE2
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import route_obstacles
from lastmile.core.safety_messages import FailSafeLevel, MrmKind
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, PassRequest, StopReason
from lastmile.decision.behaviour_memory import BehaviourMemory, CrosswalkHold, Cycle, DecisionContext, Outcome
from lastmile.decision.crosswalk_yield import stop_fits
from lastmile.decision.decision_config import DecisionConfig, DecisionInput
from lastmile.decision.drop_off import (
    DropOffPlaces,
    handle_drop_off_onboarding,
    handle_drop_off_pullover,
    start_drop_off,
)
from lastmile.decision.give_way_rule import GiveWayRule
from lastmile.decision.intersection_handling import AllWayStops, handle_intersection, next_all_way_stop_line
from lastmile.decision.mission import MissionManager
from lastmile.decision.observed_motion import observed_velocities, updated_trails
from lastmile.decision.offroad_unknowns import (
    kerbside_unknown_ids,
    road_user_ids,
    unsettled_unknown_ids,
    yieldable_tracks,
)
from lastmile.decision.pass_rule import PassInput, PassRule
from lastmile.decision.stop_constraints import (
    StopConstraint,
    crosswalk_constraints,
    cut_in_constraints,
    in_path_constraints,
    safety_constraints,
)
from lastmile.decision.stop_service import (
    handle_merging,
    handle_onboarding,
    handle_pullover,
    next_requested_stop,
)
from lastmile.decision.stop_sign_rule import StopSignRule
from lastmile.decision.traffic_light_rule import TrafficLightRule
from lastmile.hdmap.curb_fit import spot_offset_m
from lastmile.hdmap.layers import SLayerDatabase

SPOT_CACHE_SIZE = 64
_AT_THE_KERB = frozenset({BehaviourState.PULLOVER, BehaviourState.ONBOARDING, BehaviourState.MERGING})
"""States in which the body is brought to (or leaves) the kerb on purpose."""
"""Rest offsets remembered (a committed spot is asked for every cycle; the search projects ~40 points)."""


@dataclass
class BehaviourStateMachine:
    """The decision FSM; ``step`` runs once per planning cycle (10 Hz)."""

    layers: SLayerDatabase
    geometry: VehicleGeometry
    mission: MissionManager
    config: DecisionConfig = field(default_factory=DecisionConfig)
    memory: BehaviourMemory = field(default_factory=BehaviourMemory)
    can_pass: bool = False
    """Pass stationary obstacles by the adjacent lane (the planner can plan it; ``pass_rule``)."""

    def __post_init__(self) -> None:
        self.context = DecisionContext(
            layers=self.layers,
            geometry=self.geometry,
            mission=self.mission,
            config=self.config,
            route=self.layers.centerline,
        )
        self.junctions = AllWayStops.from_layers(self.layers, self.config.entry_heading_back_m)
        self.lights = TrafficLightRule(self.layers, self.config.traffic_lights)
        self.stop_signs = StopSignRule(self.layers, self.config.traffic_lights)
        self.give_way = GiveWayRule(
            self.layers, self.geometry, self.config.give_way, self.config.traffic_lights
        )
        self.passing = PassRule(self.layers, self.geometry, self.config.passing, self.can_pass)
        self.drop_offs = DropOffPlaces(self.layers, self.config.drop_off)
        self._spot_d_cache: dict[tuple[float, float], float] = {}
        self._pass_request: PassRequest | None = None
        # The give-way rule's verdict when it lets the shuttle go ("gap", "committed"), for the reason.
        self._give_way_note = ""

    @property
    def state(self) -> BehaviourState:
        return self.memory.state

    @state.setter
    def state(self, state: BehaviourState) -> None:
        self.memory.state = state

    @property
    def transitions(self) -> list[tuple[float, str, str, str]]:
        """(t_s, from state, to state, why) of every state change."""
        return self.memory.transitions

    # ------------------------------------------------------------------------------------------------
    def step(self, inp: DecisionInput) -> BehaviourDecision:
        """One planning cycle: the stop points every state respects, then the state's handler, then
        the emergency test on the nearest stop point."""
        cy = self._cycle(inp)
        outcome = _HANDLERS[self.memory.state](self, cy)
        if outcome.hold_still:
            return self._decision(cy, outcome, None)
        binding = min(cy.constraints, key=lambda k: k.stop_front_s_m, default=None)
        # The emergency test reads the nearest point that may order one, even when a rule's point
        # (a crosswalk stopping short of the same pedestrian) binds the comfortable stop.
        urgent = min(
            (k for k in cy.constraints if k.emergency_ok), key=lambda k: k.stop_front_s_m, default=None
        )
        if self._too_close(urgent, cy):
            assert urgent is not None
            self.memory.enter(
                BehaviourState.EMERGENCY_STOP, cy.t_s, f"{urgent.kind} {urgent.track_id} too close"
            )
            return self._decision(cy, self._emergency(cy), None)
        return self._decision(cy, outcome, binding)

    def request_emergency(self, t_s: float, why: str) -> None:
        """The e-stop button or a safety monitor: every state can reach emergency stop."""
        if self.memory.state != BehaviourState.EMERGENCY_STOP:
            self.memory.enter(BehaviourState.EMERGENCY_STOP, t_s, why)

    def spot_d_m(self, curb_d_m: float, rear_s_m: float) -> float:
        """Route d of the rear axle when pulled over with its rear axle at ``rear_s_m``: the curb gap
        target kept along the whole straight body, also where the curb curves (``curb_fit``)."""
        key = (curb_d_m, rear_s_m)
        if key not in self._spot_d_cache:  # a committed spot is asked for every cycle
            if len(self._spot_d_cache) > SPOT_CACHE_SIZE:
                self._spot_d_cache.clear()
            self._spot_d_cache[key] = spot_offset_m(
                self.context.route, rear_s_m, curb_d_m, self.config.curb_gap_target_m, self.geometry
            )
        return self._spot_d_cache[key]

    # --- the cycle ------------------------------------------------------------------------------
    def _cycle(self, inp: DecisionInput) -> Cycle:
        """The cycle's stop points from obstacles, cut-ins, crosswalks, lights and the fail-safe."""
        t_s = inp.stamp / 1e6
        g, c, ctx = self.geometry, self.config, self.context
        tracked = frozenset(int(i) for i in inp.tracks.ids.tolist())
        self.memory.road_user_ids = road_user_ids(inp.tracks, self.memory.road_user_ids)
        window_s = c.offroad_motion_window_s
        self.memory.track_trails = updated_trails(self.memory.track_trails, inp.tracks, t_s, window_s)
        observed = observed_velocities(self.memory.track_trails, inp.tracks, window_s)
        # Every rule below sees only the tracks it may yield to (offroad_unknowns).
        inp = dataclasses.replace(
            inp,
            tracks=yieldable_tracks(inp.tracks, self.layers.hdmap, c.offroad_unknown_horizon_s, observed),
        )
        front_s = inp.route_s_m + g.front_from_rear_axle_m
        obstacles = route_obstacles(inp.tracks, ctx.route, inp.route_s_m, g.front_from_rear_axle_m)
        speed_cap = min(c.cruise_speed_mps, self.layers.speed_limit_at(front_s))
        # The planned path, once per cycle: the corridor both obstacle checks sweep.
        path = Polyline(inp.trajectory.points[:, :2]) if inp.trajectory is not None else None
        # At the kerb a pull-over approaches on purpose, a standing unknown beyond the road's edge is
        # judged against the body itself (Lanelet2 example, snow: 0.1 m blobs on the lane's edge, 0.45 m
        # right of the body at the spot, held the shuttle 60 s short of Roundabout West).
        kerbside = (
            kerbside_unknown_ids(inp.tracks, self.layers.hdmap, c.kerbside_standing_mps)
            if self.memory.state in _AT_THE_KERB
            else frozenset()
        )
        # An unclassified track only just tracked (never a road user) brakes the shuttle for a crosswalk
        # only comfortably, and is not taken for a lead while it is beside the body.
        unsettled = unsettled_unknown_ids(inp.tracks, c.unknown_settle_s, self.memory.road_user_ids)
        constraints = in_path_constraints(obstacles, inp.speed_mps, path, g, c, front_s, kerbside, unsettled)
        constraints += cut_in_constraints(
            obstacles, inp.predictions, ctx.route, path, front_s, inp.speed_mps, g, c
        )
        yielding_to = _still_yielded_to(self.memory.crosswalk_hold, inp.tracks, t_s)
        constraints += self._crosswalk_hold(
            crosswalk_constraints(
                self.layers.crosswalks,
                ctx.route,
                inp.tracks,
                front_s,
                inp.speed_mps,
                inp.predictions,
                g,
                c,
                unsettled,
                may_pass=self.memory.crosswalk_hold is None,
                yielding_to=yielding_to,
            ),
            t_s=t_s,
            front_s_m=front_s,
            speed_mps=inp.speed_mps,
            tracked=tracked,
            unsettled=unsettled,
            yielding_to=yielding_to,
        )
        light_stop, light_why = self.lights.step(t_s, front_s, inp.speed_mps, inp.traffic_lights, ctx.ahead_m)
        if light_stop is not None:
            # Never an emergency stop for a light: a late red is braked for as hard as allowed, no harder.
            constraints.append(
                StopConstraint(light_stop, light_why, emergency_ok=False, reason=StopReason.TRAFFIC_LIGHT)
            )
        sign_stop, sign_why = self.stop_signs.step(t_s, front_s, inp.speed_mps, ctx.ahead_m)
        if sign_stop is not None:  # a two-way stop's line: a full stop, then on (stop_sign_rule)
            constraints.append(
                StopConstraint(sign_stop, sign_why, emergency_ok=False, reason=StopReason.STOP_LINE)
            )
        # Give-way lines, and the gap after a two-way stop's full stop (give_way_rule).
        given = self.give_way.step(t_s, front_s, inp.speed_mps, speed_cap, inp.tracks, ctx.ahead_m)
        self._give_way_note = given.why if given.stop_front_s_m is None else ""
        if given.stop_front_s_m is not None:
            constraints.append(
                StopConstraint(
                    given.stop_front_s_m,
                    given.why,
                    given.track_id,
                    emergency_ok=False,
                    reason=StopReason.GIVE_WAY,
                )
            )
        sd = inp.safety
        if sd is not None and sd.level != FailSafeLevel.NONE and sd.emergency_stop:
            self.request_emergency(t_s, "safety: " + "; ".join(sd.reasons))
        speed_cap, mrm = safety_constraints(sd, speed_cap)
        self._pass_request, waits = self.passing.step(
            PassInput(
                t_s=t_s,
                front_s_m=front_s,
                route_d_m=inp.route_d_m,
                speed_mps=inp.speed_mps,
                obstacles=obstacles,
                may_start=self.memory.state == BehaviourState.NORMAL_DRIVING and not mrm,
            )
        )
        if self._pass_request is not None and self._pass_request.approved:
            speed_cap = min(speed_cap, c.passing.pass_speed_mps)
        return Cycle(inp, t_s, front_s, obstacles, constraints + mrm + waits, speed_cap, unsettled)

    def _crosswalk_hold(
        self,
        yields: list[StopConstraint],
        *,
        t_s: float,
        front_s_m: float,
        speed_mps: float,
        tracked: frozenset[int],
        unsettled: frozenset[int],
        yielding_to: frozenset[int],
    ) -> list[StopConstraint]:
        """The crosswalk yields, and, for ``crosswalk_clear_s`` after the last one cleared, the one the
        shuttle stood for (only while it still stands: one that drove on has nothing to hold), or the
        one whose settled track the tracker lost (``tracked``: its ids this cycle) while it can still
        stop there comfortably. ``front_s_m``: the front bumper's route s.

        A lost track is not a person gone: in clear seed 2 a pedestrian 4.5 s tracked, walking across
        35 m ahead, was lost and the shuttle drove on at 5.5 m/s; with a 1.0 m/s^2 a_nom (clear seed
        1) one beside the crossing went missing for 0.5 s while the shuttle braked for them at
        1.6 m/s, and their return 1.1 m before the stop point ended the stop with 0.5 m/s^2 of
        braking left (+3.57 m/s^3). But a snow echo the tracker followed for 0.5 s is lost as well:
        held, it braked the shuttle to -2.9 m/s^2 (snow seed 3), so only a settled track holds, and
        never past a comfortable stop. Someone still tracked who no longer needs the yield (they
        have crossed) releases it at once. ``unsettled``: the new unclassified tracks; ``yielding_to``:
        the track of the yield under way (``_still_yielded_to``), whose stop point is kept rather
        than moved back behind the front (snow seed 2, a_nom 1.0: moving off past the line, a yield
        at the crossing's edge turned into the line behind the front, -2.76 m/s^3)."""
        c, mem = self.config, self.memory
        standing = speed_mps < c.standstill_mps
        if yields:
            first = min(yields, key=lambda k: k.stop_front_s_m)
            held = mem.crosswalk_hold
            if (
                held is not None
                and first.track_id in yielding_to
                and first.stop_front_s_m < min(front_s_m, held.stop_front_s_m)
            ):
                # A yield under way keeps its point rather than jump back to the line behind the
                # front, an overshoot the speed law brakes back from as hard as it may.
                at = yields.index(first)
                first = dataclasses.replace(first, stop_front_s_m=held.stop_front_s_m)
                yields = [*yields[:at], first, *yields[at + 1 :]]
            settled = first.track_id not in unsettled
            mem.crosswalk_hold = CrosswalkHold(first.stop_front_s_m, first.track_id, t_s, standing, settled)
            return yields
        held = mem.crosswalk_hold
        if held is None or t_s - held.seen_s >= c.crosswalk_clear_s:
            mem.crosswalk_hold = None
            return yields
        fits = stop_fits(held.stop_front_s_m - front_s_m, speed_mps, c.traffic_lights.comfort_decel_mps2)
        lost = held.settled and held.track_id not in tracked and fits
        if not (lost or (standing and held.standing)):
            mem.crosswalk_hold = None
            return yields
        return [
            StopConstraint(
                held.stop_front_s_m,
                "crosswalk (clearing)",
                held.track_id,
                emergency_ok=False,
                reason=StopReason.CROSSWALK,
            )
        ]

    def _too_close(self, binding: StopConstraint | None, cy: Cycle) -> bool:
        """Stopping at ``binding`` needs more than ``emergency_decel_mps2`` (never while onboarding)."""
        c, v = self.config, cy.inp.speed_mps
        if binding is None or not binding.emergency_ok or self.memory.state == BehaviourState.ONBOARDING:
            return False
        gap = binding.stop_front_s_m - cy.front_s_m + c.min_gap_m - c.emergency_contact_margin_m
        need = v**2 / (2.0 * max(gap, c.emergency_gap_floor_m))
        return need > c.emergency_decel_mps2 and v > c.emergency_min_speed_mps

    def _decision(self, cy: Cycle, outcome: Outcome, binding: StopConstraint | None) -> BehaviourDecision:
        """The decision of the cycle; an emergency stop (``hold_still``) stops at the front."""
        reason = outcome.reason
        if binding is not None and binding.kind not in ("spot",):
            reason = f"{reason}; stop for {binding.kind}"
        if self._give_way_note:
            reason = f"{reason}; {self._give_way_note}"
        if self._pass_request is not None and self._pass_request.approved:
            reason = f"{reason}; passing track {self._pass_request.track_id}"
        elif self.passing.memory.why:
            reason = f"{reason}; not passing: {self.passing.memory.why}"
        stop_at: float | None
        if outcome.hold_still:
            stop_at, risk, why = cy.front_s_m, outcome.risk_track_id, StopReason.EMERGENCY
        else:
            stop_at = None if binding is None else binding.stop_front_s_m
            risk = -1 if binding is None else binding.track_id
            why = StopReason.NONE if binding is None else binding.reason
        spot = self._spot_pose()
        if why == StopReason.MINIMAL_RISK_MANOEUVRE and stop_at is not None:
            spot = self._mrm_spot_pose(cy, stop_at) or spot
        return BehaviourDecision(
            stamp=cy.inp.stamp,
            state=self.memory.state,
            speed_limit_mps=outcome.speed_cap_mps,
            stop_at_s_m=stop_at,
            pullover_spot=spot,
            merge_from_s_m=self.memory.stop.merge_from_s_m,
            door_open=outcome.door_open,
            risk_track_id=risk,
            reason=reason,
            stop_reason=why,
            pass_request=self._pass_request,
        )

    # --- handlers of the states without a module of their own ------------------------------------
    def _normal_driving(self, cy: Cycle) -> Outcome:
        """Cruise; hand over to INTERSECTION near an all-way stop line, or to PULLOVER near a wanted stop."""
        mem, ctx = self.memory, self.context
        if self._pass_request is not None and self._pass_request.committed:
            # Out in the other lane: nothing may take over the path before the pass is finished (a
            # pull-over or an all-way stop starts from the lane; a stop so reached is missed).
            return Outcome(cy.speed_cap_mps, "cruise")
        line = next_all_way_stop_line(ctx, cy.front_s_m)
        if line is not None and ctx.ahead_m(line[0], cy.front_s_m) < self.config.intersection_approach_m:
            mem.enter(BehaviourState.INTERSECTION, cy.t_s, "approaching all-way stop")
            mem.intersection.line_index = line[1]
            return self._intersection(cy)
        stop = next_requested_stop(ctx, cy.front_s_m)
        if stop is not None:
            stop_id = self.layers.stops[stop].stop.id
            why = f"stop {stop_id} requested"
            if mem.drop_off.deferred_stop_id == stop_id:
                why += " (drop-off: no safe place to stop before it)"
            mem.enter(BehaviourState.PULLOVER, cy.t_s, why)
            mem.stop.stop_index = stop
            mem.stop.spot_front_s_m, mem.stop.spot_committed = None, False
            outcome = self._pullover(cy)
            if mem.drop_off.deferred_stop_id == stop_id:
                outcome = dataclasses.replace(outcome, reason=f"{outcome.reason}: {why}")
            return outcome
        # A passenger's drop-off (Snow Lion's button): to the next safe kerb, or the next stop.
        dropping = start_drop_off(ctx, mem, cy, self.drop_offs)
        if dropping is not None:
            return dropping
        if mem.drop_off.deferred_stop_id is not None:
            return Outcome(cy.speed_cap_mps, f"cruise; drop-off at stop {mem.drop_off.deferred_stop_id}")
        return Outcome(cy.speed_cap_mps, "cruise")

    def _intersection(self, cy: Cycle) -> Outcome:
        return handle_intersection(self.context, self.junctions, self.memory, cy)

    def _pullover(self, cy: Cycle) -> Outcome:
        if self.memory.drop_off.active:
            return handle_drop_off_pullover(self.context, self.memory, cy, self.drop_offs)
        return handle_pullover(self.context, self.memory, cy)

    def _onboarding(self, cy: Cycle) -> Outcome:
        mem = self.memory
        if mem.drop_off.active:
            return handle_drop_off_onboarding(self.context, mem, cy, self.config.drop_off)
        if self.mission.drop_off_pending and cy.inp.door_open and not mem.boarding.door_closing:
            mem.drop_off.door_open_for_rider = True
        outcome = handle_onboarding(self.context, mem, cy)
        if mem.state == BehaviourState.MERGING and mem.drop_off.door_open_for_rider:
            # The door cycle at a stop let the rider who asked for a drop-off get off there too (a
            # request pressed as the door was already closing waits for the next safe place).
            self.mission.drop_off_served()
            mem.drop_off.deferred_stop_id = None
        return outcome

    def _merging(self, cy: Cycle) -> Outcome:
        return handle_merging(self.context, self.memory, cy)

    def _emergency(self, cy: Cycle) -> Outcome:
        """Stand still; back to the state before once stopped ``emergency_clear_s`` with nothing moving
        close (a standing obstacle is the restored state's to stop for). An e-stop the safety module
        ordered holds until the fail-safe releases it (operator reset)."""
        c, mem, inp = self.config, self.memory, cy.inp
        reach = c.min_gap_m + c.emergency_close_m
        close = [k for k in cy.constraints if k.emergency_ok and k.stop_front_s_m - cy.front_s_m < reach]
        moving = _moving_track_ids(inp.tracks, c.emergency_hold_moving_mps)
        holding = any(k.track_id in moving for k in close)
        ordered = inp.safety is not None and inp.safety.emergency_stop
        if inp.speed_mps < c.standstill_mps and not holding and not ordered:
            if mem.emergency_clear_since_s is None:
                mem.emergency_clear_since_s = cy.t_s
            elif cy.t_s - mem.emergency_clear_since_s > c.emergency_clear_s:
                mem.emergency_clear_since_s = None
                mem.enter(mem.previous_state, cy.t_s, "emergency cleared")
        else:
            mem.emergency_clear_since_s = None
        # Hold still for this cycle even when just cleared; the next cycle plans from the restored state.
        return Outcome(
            0.0, "emergency stop", hold_still=True, risk_track_id=close[0].track_id if close else -1
        )

    def _mrm_spot_pose(self, cy: Cycle, stop_front_s_m: float) -> SE2 | None:
        """Where the rear axle rests when the safety module's manoeuvre pulls over: at the curb of the
        stop point, the curb gap kept (None: it stops in lane, or the map has no curb there)."""
        sd = cy.inp.safety
        if sd is None or sd.mrm != MrmKind.PULL_OVER:
            return None
        curb = float(self.layers.curb_right_d_m[self.layers.record_indices(np.array([stop_front_s_m]))[0]])
        if not math.isfinite(curb):
            return None
        rear_s = stop_front_s_m - self.geometry.front_from_rear_axle_m
        x, y, yaw = self.context.route.point_at(rear_s)
        d = self.spot_d_m(curb, rear_s)
        return SE2(x - d * math.sin(yaw), y + d * math.cos(yaw), yaw)

    def _spot_pose(self) -> SE2 | None:
        drop = self.memory.drop_off
        if drop.spot_front_s_m is not None:
            return self._curb_pose(drop.spot_front_s_m, drop.curb_d_m)
        visit = self.memory.stop
        if visit.spot_front_s_m is None or visit.stop_index is None:
            return None
        return self._curb_pose(visit.spot_front_s_m, self.layers.stops[visit.stop_index].curb_d_m)

    def _curb_pose(self, spot_front_s_m: float, curb_d_m: float) -> SE2:
        """Where the rear axle rests with the front at ``spot_front_s_m``, the curb gap kept."""
        rear_s = spot_front_s_m - self.geometry.front_from_rear_axle_m
        x, y, yaw = self.context.route.point_at(rear_s)
        d = self.spot_d_m(curb_d_m, rear_s)
        return SE2(x - d * math.sin(yaw), y + d * math.cos(yaw), yaw)


_HANDLERS: dict[BehaviourState, Callable[[BehaviourStateMachine, Cycle], Outcome]] = {
    BehaviourState.NORMAL_DRIVING: BehaviourStateMachine._normal_driving,
    BehaviourState.INTERSECTION: BehaviourStateMachine._intersection,
    BehaviourState.PULLOVER: BehaviourStateMachine._pullover,
    BehaviourState.ONBOARDING: BehaviourStateMachine._onboarding,
    BehaviourState.MERGING: BehaviourStateMachine._merging,
    BehaviourState.EMERGENCY_STOP: BehaviourStateMachine._emergency,
}
"""One handler per state: it may change the state, add stop points and set the cap, reason and door."""


def _moving_track_ids(tracks: TrackedObjects, faster_than_mps: float) -> frozenset[int]:
    """Ids of the tracks moving faster than ``faster_than_mps`` (ground speed)."""
    speed = np.hypot(tracks.table[:, 2], tracks.table[:, 3])
    return frozenset(int(i) for i in tracks.ids[speed > faster_than_mps])


def _still_yielded_to(held: CrosswalkHold | None, tracks: TrackedObjects, t_s: float) -> frozenset[int]:
    """The track of the crosswalk yield under way (``held``), if it is tracked now and old enough to
    be the one yielded to then (a new track may reuse an ended track's id)."""
    if held is None:
        return frozenset()
    age = tracks.table[:, TRACK_COLUMNS.index("age_s")]
    same = (tracks.ids == held.track_id) & (age >= t_s - held.seen_s - 1e-6)
    return frozenset(int(i) for i in tracks.ids[same].tolist())
