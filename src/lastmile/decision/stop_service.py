"""The bus-stop states: PULLOVER to a dynamic spot, ONBOARDING with the door sensor, MERGING (WATonoBus)."""

from __future__ import annotations

import math

from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.vehicle_messages import BehaviourState, StopReason
from lastmile.decision.behaviour_memory import BehaviourMemory, Boarding, Cycle, DecisionContext, Outcome
from lastmile.decision.decision_config import DecisionConfig, DecisionInput
from lastmile.decision.pullover_spot import SpotRequest, choose_spot
from lastmile.decision.stop_constraints import StopConstraint
from lastmile.decision.traffic_light_rule import comfortable_stop_m
from lastmile.hdmap.layers import RouteStop


def next_requested_stop(ctx: DecisionContext, front_s_m: float) -> int | None:
    """Row in ``stops`` of the first stop whose platform begins within ``stop_approach_m`` and is wanted."""
    for i, rs in enumerate(ctx.layers.stops):
        ahead = ctx.ahead_m(rs.s_start_m, front_s_m)
        if 0.0 < ahead < ctx.config.stop_approach_m and ctx.mission.wants(rs.stop.id):
            return i
    return None


def handle_pullover(ctx: DecisionContext, mem: BehaviourMemory, cy: Cycle) -> Outcome:
    """Drive to the spot the scan finds free; ONBOARDING once stopped there. A stop with no free
    spot is passed."""
    assert mem.stop.stop_index is not None
    rs = ctx.layers.stops[mem.stop.stop_index]
    c, visit = ctx.config, mem.stop
    if not visit.spot_committed:
        _rechoose_spot(ctx, mem, rs, cy)
    if visit.spot_front_s_m is None:
        if ctx.ahead_m(rs.s_end_m, cy.front_s_m) < 0.0:
            mem.finish_stop(cy.t_s, "stop blocked: no free spot")
        return Outcome(cy.speed_cap_mps, "stop blocked: no free spot, passing")
    cy.constraints.append(StopConstraint(visit.spot_front_s_m, "spot", -1, False, StopReason.BUS_STOP))
    arrived = (
        abs(visit.spot_front_s_m - cy.front_s_m) < c.spot_arrival_m and cy.inp.speed_mps < c.standstill_mps
    )
    if arrived:
        mem.enter(BehaviourState.ONBOARDING, cy.t_s, "at pull-over spot")
        mem.boarding = Boarding()
    cap = cy.speed_cap_mps
    if ctx.ahead_m(visit.spot_front_s_m, cy.front_s_m) < c.stop_approach_m:
        cap = min(cap, c.pullover_speed_mps)
    return Outcome(cap, "pulling over")


def _rechoose_spot(ctx: DecisionContext, mem: BehaviourMemory, rs: RouteStop, cy: Cycle) -> None:
    """The spot is chosen anew every cycle from what the scan sees (WATonoBus, Sec. bus-stop
    handling): a car parked further along the bay only shows up as the shuttle nears it. It is
    committed once within ``spot_commit_m`` with room to spare: it no longer moves."""
    c, g, visit = ctx.config, ctx.geometry, mem.stop
    lane_right = float(ctx.layers.lane_right_at(rs.s_start_m + c.platform_lane_probe_m))
    stopping_m = cy.inp.speed_mps**2 / (2.0 * c.spot_stopping_decel_mps2)
    request = SpotRequest(
        platform_start_s_m=rs.s_start_m,
        platform_end_s_m=rs.s_end_m,
        bay_edge_d_m=lane_right,
        curb_d_m=rs.curb_d_m,
        vehicle_length_m=g.length_m,
        transition_m=c.transition_m * c.spot_transition_share,
        margin_m=c.min_gap_m + c.spot_extra_margin_m,
        preferred_front_s_m=0.5 * (rs.s_start_m + rs.s_end_m) + g.length_m / 2.0,
        exit_m=c.merge_room_m,
        earliest_front_s_m=cy.front_s_m + stopping_m if visit.spot_front_s_m is not None else -math.inf,
    )
    seen = [o for o in cy.obstacles if o.ds_m < c.spot_scan_m + o.length_m]
    spot = choose_spot(request, seen)
    if spot is not None or visit.spot_front_s_m is None:
        visit.spot_front_s_m = spot
    if (
        visit.spot_front_s_m is not None
        and ctx.ahead_m(visit.spot_front_s_m + c.merge_room_m, cy.front_s_m) < c.spot_commit_m
    ):
        visit.spot_committed = True


def handle_onboarding(ctx: DecisionContext, mem: BehaviourMemory, cy: Cycle) -> Outcome:
    """Door open at least ``dwell_min_s`` and until the doorway has been clear ``doorway_clear_s``;
    MERGING once the door is closed (the stop then counts as served)."""
    inp, t_s = cy.inp, cy.t_s
    cy.constraints.append(StopConstraint(cy.front_s_m, "onboarding", -1, False, StopReason.ONBOARDING))
    door = door_cycle(ctx.config, mem.boarding, inp, t_s, cy.speed_cap_mps)
    if door is not None:
        return door
    if mem.stop.stop_index is not None:
        ctx.mission.served(ctx.layers.stops[mem.stop.stop_index].stop.id)
    mem.enter(BehaviourState.MERGING, t_s, "door closed")
    mem.stop.merge_from_s_m = inp.route_s_m
    return Outcome(cy.speed_cap_mps, "closing door")


def door_cycle(
    c: DecisionConfig, b: Boarding, inp: DecisionInput, t_s: float, cap_mps: float
) -> Outcome | None:
    """The door's cycle at a standstill (a stop or a drop-off): open at least ``dwell_min_s`` and until
    the doorway has been clear ``doorway_clear_s``, then closed; None once it has closed."""
    if b.door_closing:
        if not inp.door_open:
            return None
        return Outcome(cap_mps, "closing door")
    if inp.door_open and b.door_open_since_s is None:
        b.door_open_since_s = t_s
    if inp.person_in_doorway or not inp.door_open:
        b.doorway_clear_since_s = None
    elif b.doorway_clear_since_s is None:
        b.doorway_clear_since_s = t_s
    if (
        b.door_open_since_s is not None
        and t_s - b.door_open_since_s >= c.dwell_min_s
        and b.doorway_clear_since_s is not None
        and t_s - b.doorway_clear_since_s >= c.doorway_clear_s
    ):
        b.door_closing = True
        return Outcome(cap_mps, "closing door")
    return Outcome(cap_mps, "passengers boarding", door_open=True)


def handle_merging(ctx: DecisionContext, mem: BehaviourMemory, cy: Cycle) -> Outcome:
    """Out of the bay at ``merge_speed_mps``, waiting while traffic from the rear would reach the
    shuttle; NORMAL_DRIVING once back on the lane centre."""
    c, inp, visit = ctx.config, cy.inp, mem.stop
    if (
        abs(inp.route_d_m) < c.merged_max_offset_m
        and visit.merge_from_s_m is not None
        and inp.route_s_m - visit.merge_from_s_m > c.merged_after_m
    ):
        mem.finish_stop(cy.t_s, "merged")
        return Outcome(cy.speed_cap_mps, "merged")
    cap = min(cy.speed_cap_mps, c.merge_speed_mps)
    # Rear traffic is judged over rear_tta_s (7 s): an unclassified track is waited for once it has
    # settled, 1 s on (a snow echo beside the shuttle, 0.1 m across and 0.3-0.6 s old, held two merges).
    blocker = rear_blocker(ctx, [o for o in cy.obstacles if o.track_id not in cy.unsettled_ids])
    if blocker >= 0 and (
        visit.merge_from_s_m is None or inp.route_s_m - visit.merge_from_s_m < c.merge_hold_m
    ):
        # Where a comfortable stop from the speed the hold finds ends, fixed for the hold: at the front
        # itself, a hold at the merge's 1 m/s was braked for at the urgent rate (-2.8 m/s^3, snow, raw).
        # The shuttle is still within merge_hold_m of the bay; anything in its path is the in-path
        # rule's, which may order an emergency stop.
        # Moving off, that stop counts the acceleration (snow seed 2: at 0.52 m/s and 0.97 m/s^2 a hold
        # 0.34 m ahead, a steady speed's, was braked for at -2.70 m/s^3).
        if visit.rear_hold_front_s_m is None:
            room_m = comfortable_stop_m(inp.speed_mps, c.traffic_lights, inp.accel_mps2)
            visit.rear_hold_front_s_m = cy.front_s_m + room_m
        cy.constraints.append(
            StopConstraint(visit.rear_hold_front_s_m, "rear_traffic", blocker, False, StopReason.REAR_TRAFFIC)
        )
        # The merge began where the door closed, and a hold does not move that point: moved along at
        # every hold, the window ratcheted with the shuttle, and a car following it out of a kerbside
        # stop held it at a crawl for 171 s (BITS, snow, raw: stop-and-go at 0.2-1.6 m/s).
        if visit.merge_from_s_m is None:
            visit.merge_from_s_m = inp.route_s_m
        return Outcome(cap, "waiting: traffic from the rear")
    visit.rear_hold_front_s_m = None
    return Outcome(cap, "merging")


def rear_blocker(ctx: DecisionContext, obstacles: list[RouteObstacle]) -> int:
    """Track id of a road user behind that the merge must wait for, else -1: one within
    ``rear_too_close_m`` of the rear, or one within ``rear_check_m`` reaching it within ``rear_tta_s``.

    A road user standing wholly behind the rear bumper is waiting for the shuttle, not passing it: at a
    kerbside stop (no bay) the shuttle stands in the lane and the car queued behind it cannot pass, so
    waiting for it would wait for ever; traffic behind must let a bus leave its stop (StVO 20(5), Ontario
    HTA 142.1). It holds the merge only while it is beside the shuttle or moving.
    """
    c, g = ctx.config, ctx.geometry
    for o in obstacles:
        behind = -(o.ds_m + g.length_m)  # distance from our rear bumper back to the object
        if behind < -g.length_m or behind > c.rear_check_m or abs(o.d_m) > c.rear_half_width_m:
            continue
        if behind > 0.0 and abs(o.v_s_mps) < c.rear_min_closing_mps:
            continue  # standing behind us: it yields to a bus leaving its stop
        if behind < c.rear_too_close_m:
            return o.track_id
        if o.v_s_mps > c.rear_min_closing_mps and behind / o.v_s_mps < c.rear_tta_s:
            return o.track_id
    return -1
