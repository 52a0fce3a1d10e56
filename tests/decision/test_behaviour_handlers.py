"""The decision FSM's per-state handlers and shared stop points, each called on its own."""

from __future__ import annotations

import dataclasses
import functools
import math

import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.route_obstacles import route_obstacles
from lastmile.core.safety_messages import FailSafeLevel, MrmKind, SafetyDirective
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourState, StopReason
from lastmile.decision.behaviour_fsm import _HANDLERS, BehaviourStateMachine
from lastmile.decision.behaviour_memory import BehaviourMemory, Cycle, DecisionContext
from lastmile.decision.decision_config import DecisionConfig, DecisionInput
from lastmile.decision.intersection_handling import AllWayStops, handle_intersection, next_all_way_stop_line
from lastmile.decision.mission import MissionManager
from lastmile.decision.stop_constraints import in_path_constraints, lead_stop_s_m, safety_constraints
from lastmile.decision.stop_service import handle_merging, handle_onboarding, handle_pullover, rear_blocker
from lastmile.decision.traffic_light_rule import comfortable_stop_m
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop
from tests.decision.test_behaviour_fsm import G, _inp, _tracks

C = DecisionConfig()


def _ctx(layers: SLayerDatabase) -> DecisionContext:
    mission = MissionManager(stop_order=tuple(rs.stop.id for rs in layers.stops))
    return DecisionContext(layers=layers, geometry=G, mission=mission, config=C, route=layers.centerline)


def _cycle(ctx: DecisionContext, inp: DecisionInput, cap: float = 5.0) -> Cycle:
    front = inp.route_s_m + G.front_from_rear_axle_m
    obstacles = route_obstacles(inp.tracks, ctx.route, inp.route_s_m, G.front_from_rear_axle_m)
    return Cycle(inp, inp.stamp / 1e6, front, obstacles, [], cap)


@functools.cache
def _campus_layers() -> SLayerDatabase:
    hdmap = load_campus_map()
    return SLayerDatabase.build(hdmap, campus_shuttle_loop(hdmap), step_m=1.0, closed=True)


# --- shared stop points ------------------------------------------------------------------------
def test_lead_stop_point_adds_the_braking_distance_of_a_lead_moving_away_only() -> None:
    assert lead_stop_s_m(100.0, 4.0, 6.0, 3.0) == 100.0 - 2.0 + 6.0
    assert lead_stop_s_m(100.0, 4.0, -6.0, 3.0) == 98.0


def test_in_path_stops_for_what_is_in_the_corridor_within_the_lookahead(straight_layers) -> None:
    ctx = _ctx(straight_layers)
    front = 50.0 + G.front_from_rear_axle_m

    def stops(x: float, y: float, vx: float = 0.0, vy: float = 0.0, cls=ObjectClass.CAR) -> list[float]:
        inp = _inp(0.0, 50.0, v=5.0, tracks=_tracks([(9, x, y, vx, vy, cls)]))
        obstacles = route_obstacles(inp.tracks, ctx.route, 50.0, G.front_from_rear_axle_m)
        return [k.stop_front_s_m for k in in_path_constraints(obstacles, 5.0, None, G, C, front)]

    assert stops(front + 20.0, 0.0) == [front + 20.0 - 2.25 - C.min_gap_m]
    assert stops(front + 20.0, 5.0) == []  # beside the lane
    assert stops(front + C.in_path_lookahead_m + 5.0, 0.0) == []  # too far ahead to matter yet
    # A pedestrian walking in from the side within the time the shuttle needs to get there.
    assert len(stops(front + 20.0, 4.0, vy=-1.5, cls=ObjectClass.PEDESTRIAN)) == 1
    # Alongside, behind the front and going our way: not stopped for.
    assert stops(front - 3.0, 0.0, vx=5.0) == []


def test_in_path_stop_past_the_loops_start_is_ahead_not_a_lap_behind() -> None:
    """Near the end of a loop, an obstacle just past its start (route s near 0) is ahead: its stop
    point is in the front's lap. Taken from its own route s it read a lap behind the front, an
    emergency stop that never cleared (the Lanelet2 example's 192 m loop, raw perception in snow)."""
    layers = _campus_layers()
    ctx = _ctx(layers)
    route = ctx.route
    rear_s = route.length_m - 10.0
    front = rear_s + G.front_from_rear_axle_m
    x, y, _ = route.point_at(12.0)  # 22 m ahead of the rear axle, across s = 0
    inp = _inp(0.0, rear_s, v=5.0, tracks=_tracks([(9, x, y, 0.0, 0.0, ObjectClass.CAR)]))
    obstacles = route_obstacles(inp.tracks, route, rear_s, G.front_from_rear_axle_m)
    (k,) = in_path_constraints(obstacles, 5.0, None, G, C, front)
    assert k.stop_front_s_m == pytest.approx(route.length_m + 12.0 - 2.25 - C.min_gap_m, abs=0.05)
    assert k.stop_front_s_m > front


def test_safety_directive_caps_the_speed_and_adds_the_manoeuvre_stop() -> None:
    def directive(level: FailSafeLevel, cap: float | None, stop_s: float | None) -> SafetyDirective:
        mrm = MrmKind.STOP_IN_LANE if stop_s else MrmKind.NONE
        return SafetyDirective(
            stamp=Stamp(0), level=level, speed_cap_mps=cap, mrm=mrm, mrm_decel_mps2=1.0, mrm_stop_s_m=stop_s,
            emergency_stop=False, takeover_request=False, since_us=0, reasons=(),
        )  # fmt: skip

    assert safety_constraints(None, 5.0) == (5.0, [])
    assert safety_constraints(directive(FailSafeLevel.SPEED_LIMIT, 1.0, None), 5.0) == (1.0, [])
    cap, stops = safety_constraints(directive(FailSafeLevel.MINIMAL_RISK_MANOEUVRE, None, 80.0), 5.0)
    assert cap == 5.0 and len(stops) == 1
    assert stops[0].stop_front_s_m == 80.0 and not stops[0].emergency_ok


# --- bus-stop states ---------------------------------------------------------------------------
def test_pullover_picks_a_spot_on_the_platform_and_hands_over_at_standstill(straight_layers) -> None:
    ctx, mem = _ctx(straight_layers), BehaviourMemory(state=BehaviourState.PULLOVER)
    mem.stop.stop_index = 0
    out = handle_pullover(ctx, mem, _cycle(ctx, _inp(0.0, 170.0, v=5.0)))
    spot = mem.stop.spot_front_s_m
    assert spot is not None and 204.0 <= spot <= 224.0 and out.reason == "pulling over"
    assert out.speed_cap_mps == C.pullover_speed_mps
    rear = spot - G.front_from_rear_axle_m
    handle_pullover(ctx, mem, _cycle(ctx, _inp(1.0, rear, d_m=-3.6, v=0.0)))
    assert mem.state == BehaviourState.ONBOARDING


def test_pullover_passes_a_stop_whose_bay_is_full(straight_layers) -> None:
    ctx, mem = _ctx(straight_layers), BehaviourMemory(state=BehaviourState.PULLOVER)
    mem.stop.stop_index = 0
    parked = _tracks([(k, 202.0 + 5.0 * k, -3.6, 0.0, 0.0, ObjectClass.CAR) for k in range(5)])
    out = handle_pullover(ctx, mem, _cycle(ctx, _inp(0.0, 170.0, v=5.0, tracks=parked)))
    assert mem.stop.spot_front_s_m is None and "no free spot" in out.reason
    assert mem.state == BehaviourState.PULLOVER  # not yet past the platform
    handle_pullover(ctx, mem, _cycle(ctx, _inp(1.0, 225.0, v=5.0, tracks=parked)))
    assert mem.state == BehaviourState.NORMAL_DRIVING and mem.stop.stop_index is None


def test_onboarding_keeps_the_door_open_for_the_dwell_and_a_clear_doorway(straight_layers) -> None:
    ctx, mem = _ctx(straight_layers), BehaviourMemory(state=BehaviourState.ONBOARDING)
    ctx.mission.requested.add("S1")
    mem.stop.stop_index = 0

    def at(t_s: float, door: bool, person: bool = False):
        return handle_onboarding(ctx, mem, _cycle(ctx, _inp(t_s, 210.0, d_m=-3.6, door=door, person=person)))

    assert at(0.0, door=False).door_open  # asks for the door to open
    assert at(1.0, door=True, person=True).door_open
    assert at(1.0 + C.dwell_min_s, door=True).door_open  # dwell over, but the doorway only just cleared
    out = at(1.0 + C.dwell_min_s + C.doorway_clear_s, door=True)
    assert not out.door_open and out.reason == "closing door"
    at(10.5, door=False)
    assert mem.state == BehaviourState.MERGING and mem.stop.merge_from_s_m == 210.0
    assert not ctx.mission.wants("S1")


def test_rear_blocker_waits_for_close_or_fast_closing_traffic(straight_layers) -> None:
    ctx = _ctx(straight_layers)
    rear_bumper = 210.0 - G.rear_overhang_m

    def blocker(behind_m: float, vx: float) -> int:
        tracks = _tracks([(7, rear_bumper - behind_m - 2.25, 0.0, vx, 0.0, ObjectClass.CAR)])
        return rear_blocker(ctx, route_obstacles(tracks, ctx.route, 210.0, G.front_from_rear_axle_m))

    assert blocker(5.0, 2.0) == 7  # within rear_too_close_m and moving
    # Standing behind the shuttle (a car queued behind it at a kerbside stop): it waits for the shuttle,
    # which merges (holding the merge for it waited for ever, a stall takeover on the example town).
    assert blocker(5.0, 0.0) == -1
    assert blocker(40.0, 1.0) == -1  # 40 s away
    assert blocker(40.0, 10.0) == 7  # 4 s away, under rear_tta_s
    assert blocker(C.rear_check_m + 5.0, 20.0) == -1  # beyond the rear check


def test_rear_traffic_holds_the_merge_only_near_where_it_began(straight_layers) -> None:
    """A car following 5 m behind at 1 m/s holds a merge that began (the door closed) at s 210 while
    the shuttle is within ``merge_hold_m`` of it, and no further: a hold does not move where the merge
    began (it did, and a car following the shuttle out of a kerbside stop held it at a crawl for 171 s)."""
    ctx, mem = _ctx(straight_layers), BehaviourMemory(state=BehaviourState.MERGING)
    mem.stop.stop_index, mem.stop.merge_from_s_m = 0, 210.0

    def merge(t_s: float, rear_s: float) -> str:
        follower = rear_s - G.rear_overhang_m - 5.0 - 2.25
        car = _tracks([(7, follower, 0.0, 1.0, 0.0, ObjectClass.CAR)])
        inp = _inp(t_s, rear_s, d_m=-2.0, v=1.0, tracks=car)
        return handle_merging(ctx, mem, _cycle(ctx, inp)).reason

    assert merge(0.0, 211.0) == "waiting: traffic from the rear"
    assert mem.stop.merge_from_s_m == 210.0
    assert merge(1.0, 210.0 + C.merge_hold_m + 0.5) == "merging"


def test_a_rear_traffic_hold_stops_where_a_comfortable_stop_ends(straight_layers) -> None:
    """At the merge's speed a stop point at the front itself is braked for at the urgent rate (snow,
    raw: -2.8 m/s^3, held by a snow phantom): the hold stops where a comfortable stop ends, fixed
    while it lasts, and placed anew for the next hold."""
    ctx, mem = _ctx(straight_layers), BehaviourMemory(state=BehaviourState.MERGING)
    mem.stop.stop_index, mem.stop.merge_from_s_m = 0, 210.0

    def merge(t_s: float, rear_s: float, v: float, follower: bool = True) -> Cycle:
        car = _tracks([(7, rear_s - G.rear_overhang_m - 5.0 - 2.25, 0.0, 1.0, 0.0, ObjectClass.CAR)])
        cy = _cycle(ctx, _inp(t_s, rear_s, d_m=-2.0, v=v, tracks=car if follower else None))
        handle_merging(ctx, mem, cy)
        return cy

    cy = merge(0.0, 210.5, 1.2)
    (hold,) = cy.constraints
    want = cy.front_s_m + comfortable_stop_m(1.2, C.traffic_lights)
    assert hold.reason is StopReason.REAR_TRAFFIC and hold.stop_front_s_m == pytest.approx(want)
    assert hold.stop_front_s_m > cy.front_s_m + 1.2**2 / (2.0 * C.traffic_lights.comfort_decel_mps2)
    (later,) = merge(0.5, 211.0, 0.6).constraints
    assert later.stop_front_s_m == hold.stop_front_s_m  # fixed for the hold
    assert merge(1.0, 211.2, 0.3, follower=False).constraints == []
    assert mem.stop.rear_hold_front_s_m is None  # released
    (again,) = merge(1.5, 211.2, 0.0).constraints
    assert again.stop_front_s_m == pytest.approx(211.2 + G.front_from_rear_axle_m)  # at rest: where it stands


def test_a_rear_traffic_hold_while_moving_off_counts_the_acceleration(straight_layers) -> None:
    """Snow seed 2: merging off at 0.52 m/s and 0.97 m/s^2, a hold placed where a stop from a steady
    0.52 m/s ends (0.34 m) was braked for at -2.70 m/s^3; ramping the acceleration out first, the
    stop ends 1.28 m ahead."""
    ctx, mem = _ctx(straight_layers), BehaviourMemory(state=BehaviourState.MERGING)
    mem.stop.stop_index, mem.stop.merge_from_s_m = 0, 210.0
    car = _tracks([(7, 210.5 - G.rear_overhang_m - 5.0 - 2.25, 0.0, 1.0, 0.0, ObjectClass.CAR)])
    cy = _cycle(ctx, _inp(0.0, 210.5, d_m=-2.0, v=0.52, tracks=car, a=0.97))
    handle_merging(ctx, mem, cy)
    (hold,) = cy.constraints
    assert hold.reason is StopReason.REAR_TRAFFIC
    moving_off_m = comfortable_stop_m(0.52, C.traffic_lights, 0.97)
    assert hold.stop_front_s_m == pytest.approx(cy.front_s_m + moving_off_m)
    assert hold.stop_front_s_m - cy.front_s_m > 1.25 > 0.35 > comfortable_stop_m(0.52, C.traffic_lights)


def test_an_unclassified_track_holds_a_merge_only_once_it_has_settled(straight_layers) -> None:
    ctx, mem = _ctx(straight_layers), BehaviourMemory(state=BehaviourState.MERGING)
    mem.stop.stop_index, mem.stop.merge_from_s_m = 0, 210.0
    beside = _tracks([(7, 205.0, -1.0, 2.0, 0.0, ObjectClass.UNKNOWN)])
    young = dataclasses.replace(
        _cycle(ctx, _inp(0.0, 210.5, d_m=-2.0, v=1.0, tracks=beside)), unsettled_ids={7}
    )
    assert handle_merging(ctx, mem, young).reason == "merging"
    settled = _cycle(ctx, _inp(0.1, 210.6, d_m=-2.0, v=1.0, tracks=beside))
    assert handle_merging(ctx, mem, settled).reason == "waiting: traffic from the rear"


def test_merging_ends_back_on_the_lane_centre(straight_layers) -> None:
    ctx, mem = _ctx(straight_layers), BehaviourMemory(state=BehaviourState.MERGING)
    mem.stop.stop_index, mem.stop.merge_from_s_m = 0, 210.0
    out = handle_merging(ctx, mem, _cycle(ctx, _inp(0.0, 212.0, d_m=-2.0, v=2.0)))
    assert out.reason == "merging" and out.speed_cap_mps == C.merge_speed_mps
    out = handle_merging(ctx, mem, _cycle(ctx, _inp(1.0, 216.0, d_m=-0.1, v=2.0)))
    assert out.reason == "merged" and mem.state == BehaviourState.NORMAL_DRIVING
    assert mem.stop.stop_index is None and mem.stop.merge_from_s_m is None


# --- intersection ------------------------------------------------------------------------------
def test_intersection_full_stop_then_go_then_cleared() -> None:
    layers = _campus_layers()
    ctx = _ctx(layers)
    junctions = AllWayStops.from_layers(layers, C.entry_heading_back_m)
    (line_s, line_index) = next_all_way_stop_line(ctx, 0.0) or (None, None)
    assert line_index is not None
    mem = BehaviourMemory(state=BehaviourState.INTERSECTION)
    mem.intersection.line_index = line_index
    handle = functools.partial(handle_intersection, ctx, junctions, mem)
    front_at_line = line_s - C.stop_line_setback_m
    rear_at_line = front_at_line - G.front_from_rear_axle_m
    cy = _cycle(ctx, _inp(0.0, rear_at_line - 10.0, v=4.0))
    assert handle(cy).reason == "full stop"
    assert [k.stop_front_s_m for k in cy.constraints] == [front_at_line]
    assert handle(_cycle(ctx, _inp(1.0, rear_at_line, v=0.0))).reason == "full stop"
    assert handle(_cycle(ctx, _inp(1.0 + C.full_stop_s, rear_at_line, v=0.0))).reason == "right of way: go"
    past = line_s + C.intersection_cleared_m + 1.0 - G.front_from_rear_axle_m
    assert handle(_cycle(ctx, _inp(5.0, past, v=4.0))).reason == "cleared intersection"
    assert mem.state == BehaviourState.NORMAL_DRIVING and mem.intersection.line_index is None


def test_a_first_arrival_that_never_takes_its_turn_waves_the_shuttle_through() -> None:
    """A car stopped at another entry before the shuttle is owed the turn; standing there
    ``unclaimed_turn_s`` past the shuttle's full stop, it leaves the turn to the shuttle (a simulated
    car and the stack each judged the other first at the example town's T: both waited 300 s)."""
    layers = _campus_layers()
    ctx = _ctx(layers)
    junctions = AllWayStops.from_layers(layers, C.entry_heading_back_m)
    (line_s, line_index) = next_all_way_stop_line(ctx, 0.0) or (None, None)
    assert line_index is not None
    rl = layers.stop_lines[line_index]
    other = next(e for e in junctions.entries[rl.all_way_stop_id] if e.stop_line_id != rl.stop_line.id)
    # 3 m before the other entry's line, standing.
    x = other.mid_x_m - 3.0 * math.cos(other.heading_rad)
    y = other.mid_y_m - 3.0 * math.sin(other.heading_rad)
    car = _tracks([(9, x, y, 0.0, 0.0, ObjectClass.CAR)])
    mem = BehaviourMemory(state=BehaviourState.INTERSECTION)
    mem.intersection.line_index = line_index
    handle = functools.partial(handle_intersection, ctx, junctions, mem)
    rear_at_line = line_s - C.stop_line_setback_m - G.front_from_rear_axle_m
    assert handle(_cycle(ctx, _inp(0.0, rear_at_line - 10.0, v=4.0, tracks=car))).reason.startswith("yield")
    assert handle(_cycle(ctx, _inp(1.0, rear_at_line, v=0.0, tracks=car))).reason.startswith("yield")
    waited = 1.0 + C.full_stop_s + C.unclaimed_turn_s
    assert handle(_cycle(ctx, _inp(waited - 0.1, rear_at_line, v=0.0, tracks=car))).reason.startswith("yield")
    assert handle(_cycle(ctx, _inp(waited, rear_at_line, v=0.0, tracks=car))).reason == "right of way: go"


# --- the machine -------------------------------------------------------------------------------
def test_every_state_has_a_handler_and_an_emergency_holds_still(straight_layers) -> None:
    assert set(_HANDLERS) == set(BehaviourState)
    fsm = BehaviourStateMachine(layers=straight_layers, geometry=G, mission=_ctx(straight_layers).mission)
    fsm.request_emergency(1.0, "test")
    d = fsm.step(_inp(1.0, 20.0, v=3.0))
    assert d.state == BehaviourState.EMERGENCY_STOP and d.speed_limit_mps == 0.0
    assert d.stop_at_s_m == pytest.approx(20.0 + G.front_from_rear_axle_m)


def test_config_rejects_a_fractional_step_count_and_a_zero_divisor() -> None:
    with pytest.raises(ConfigError, match="in_path_prediction_steps"):
        DecisionConfig(in_path_prediction_steps=4.0)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="lead_decel_mps2"):
        DecisionConfig(lead_decel_mps2=0.0)
