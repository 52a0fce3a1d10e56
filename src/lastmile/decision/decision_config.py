"""What the decision module is configured with and what it is given each planning cycle."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.objects import TrackedObjects
from lastmile.core.predictions import PredictedPaths
from lastmile.core.safety_messages import SafetyDirective
from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import TrafficLightStates
from lastmile.core.vehicle_messages import Trajectory
from lastmile.decision.drop_off_config import DropOffConfig
from lastmile.decision.give_way_config import GiveWayConfig
from lastmile.decision.pass_config import PassConfig
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig
from lastmile.hdmap.curb_fit import CURB_GAP_TARGET_M


@dataclass(frozen=True, slots=True, kw_only=True)
class DecisionConfig:
    """Parameters of the decision module (units in names).

    Sources are named per field; where none is, the value is our reasoning, given beside it. The fields
    from ``in_path_lookahead_m`` on were inline numbers of the state machine, with the same defaults.

    Attributes:
        cruise_speed_mps: reference speed in normal driving (WATonoBus: 20 km/h).
        merge_speed_mps: lower cap while merging, to be able to stop for anything from the rear.
        pullover_speed_mps: cap while entering the bay.
        min_gap_m: Delta s_min of eq. (2), the gap kept to a stopped obstacle.
        corridor_margin_m: lateral clearance added to half widths for the in-path test.
        kerbside_margin_m: the same for a standing unclassified object centred off the road surface
            while the shuttle pulls over to, stands at or leaves a stop: the pull-over brings the
            body to ``curb_gap_target_m`` (0.2 m) of the kerb on purpose, so the lane's 0.5 m margin
            stopped it for anything lying at the kerb (snow on the lane's edge). Half the gap target:
            what stands beyond the edge is yielded to if the body would come within 0.1 m of it.
        kerbside_standing_mps: such an object counts as standing below this speed (a 0.1 m LiDAR blob's
            velocity estimate wanders up to 0.6 m/s; a walking person moves at 1.2-1.4 m/s).
        emergency_decel_mps2: if stopping for an obstacle needs more than this, emergency stop.
        stop_approach_m: distance before a requested stop's platform at which pull-over begins.
        intersection_approach_m: distance before an all-way stop line at which intersection handling begins.
        full_stop_s: how long the shuttle stands at a stop line before it may go.
        unclaimed_turn_s: at an all-way stop, a vehicle that arrived first and still stands this long
            after the shuttle's own full stop is waving it through (drivers' handbooks: go when the other
            driver signals you to); two vehicles that each saw the other stop first otherwise wait for ever.
            The box must still be clear.
        dwell_min_s, doorway_clear_s: onboarding: the door stays open at least dwell_min_s, and until
            the doorway has been clear for doorway_clear_s (the in-door sensor).
        rear_check_m, rear_tta_s: merging waits while a road user within rear_check_m behind would
            reach the shuttle within rear_tta_s.
        curb_gap_target_m: distance kept between the shuttle's side and the curb at a stop.
        crosswalk_margin_m: how far beyond a crosswalk's ends a waiting pedestrian counts as crossing.
        crosswalk_lookahead_s: a pedestrian or cyclist whose constant-velocity path reaches that zone
            before the shuttle has cleared the crosswalk (at most this far ahead) counts as well: at
            20 km/h the shuttle needs about 10 m to stop comfortably, and someone walking to the kerb
            covers 5 m in that time. So does a map-aware predicted path (``DecisionInput.predictions``,
            mode ``to_crosswalk``) that reaches the zone within the same time.
        offroad_unknown_horizon_s: an unclassified track off the road surface is yielded to only
            when its constant-velocity path enters the surface within this time
            (``decision.offroad_unknowns``); the crosswalk look-ahead, the longest any yield rule
            looks ahead, so nothing a rule could still yield to is dropped.
        offroad_motion_window_s: such a track's path must enter the surface at the velocity its
            published positions bear out over at least this long, as well as at the filter's
            (``decision.observed_motion``): the filter read a standing sign post beside a crosswalk,
            9 s tracked, as walking towards the road at 0.67 m/s (snow, seed 0, a_nom 1.0). One
            second, the settle time of a new unclassified track: a cluster's centre wanders by a
            few centimetres between sweeps, and someone stepping off the kerb has moved half a
            metre or more in it.
        unknown_settle_s: until an unclassified track has been tracked this long, the crosswalk rule
            yields to it only while a comfortable stop still fits (``crosswalk_yield``), and the
            merge does not wait for it (rear traffic is judged over rear_tta_s, 7 s). Snow and rain
            echoes gather near the window (Charron et al. 2018: mostly within 5-10 m) and the
            tracker turns a few into short-lived unknown tracks: in the default service (snow, raw)
            one 0.3-0.9 s old, 0.8 m long, keeping pace 4.8 m beside the shuttle with no road user
            within 15 m, made the crosswalk rule brake at the urgent rate (-2.8 m/s^2), and 0.1 m
            ones 0.3-0.6 s old held two merges (-2.8 m/s^3). 1 s is ten LiDAR sweeps. A person first
            seen far enough off is yielded to at once, as before; classified road users count from
            birth (and stay road users while tracked, whatever their class reads later), and the
            in-path rule, which may order an emergency stop, sees every track ahead of the front from
            birth (beside the body, a new unclassified one is an echo: ``behind_front_ignore_m``).
        vehicle_prediction_horizon_s: how far ahead a vehicle's lane-following predicted path
            (``DecisionInput.predictions``) is searched for where it enters the corridor (a car
            turning in from a side road); the shuttle then follows it from there
            (``decision.vehicle_cut_in``). 4 s: the look-ahead the in-path test gives pedestrians.
        cut_in_pass_margin_s: such a car is yielded to unless the shuttle's front would reach the
            entry at least this long before the car, or (a car crossing the lane) the car will have
            left the corridor at least this long before the front gets there.
        crosswalk_pass_margin_s: a crosswalk yield that no comfortable stop fits is not made for
            someone whose futures reach the shuttle's corridor (half width plus
            ``corridor_margin_m``) only this long after the shuttle, at its speed, has cleared the
            crossing (``crosswalk_yield``): it passes first. The cut-in rule's margin.
        merge_room_m: room kept free ahead of a stopped shuttle's front so it can pull out around a
            car parked further along the bay (with min_gap_m + 0.5 beyond it). 4 m, not 5: every
            metre given here is taken from the swing in, and with a car at the end of S1's 24 m
            platform a 5 m room left the swing so steep that the front corner grazed the curb.
        spot_scan_m: how far ahead of the front the pull-over spot scan looks. WATonoBus scans 20 m;
            our docking approach (curve, swing-in, 24 m platform) is longer than that, and a spot that
            moves back once a parked car comes into view leaves no room to swing in, so we look as far
            as the radar tracks reliably.
        transition_m: route length a pull-over needs (the planner's curve plus its straight settle),
            kept clear of obstacles when the spot is chosen.
        in_path_lookahead_m: obstacles further ahead of the front (route s) are not checked for the
            in-path test: well beyond the 15 m the shuttle needs to stop comfortably (1 m/s^2) from
            cruise speed, and beyond the 20 m WATonoBus's decisions look at.
        vulnerable_horizon_s: a pedestrian's or cyclist's constant-velocity motion is followed for the
            time the shuttle needs to reach it, at most this long (Snow Lion's constant-velocity check).
        vulnerable_reach_min_speed_mps: that time is taken at no less than this speed, so a slow or
            standing shuttle does not look arbitrarily far into the future.
        in_path_prediction_steps: the predicted motion is tested at this many equal steps (plus now).
        behind_front_ignore_m: an obstacle whose centre is more than this behind the front and which
            moves along the route is not stopped for (it is beside or behind us, going our way); a new
            unclassified one (``unknown_settle_s``) as soon as its centre is behind the front.
        lead_decel_mps2: how hard a lead is assumed to brake when it stops, which places the point
            eq. (2)'s gap is kept to (a firm but ordinary brake of a car).
        emergency_contact_margin_m: the emergency test asks whether the shuttle can stop this short of
            the obstacle itself (its stop point plus min_gap_m): the comfort gap may be given up, not
            this last margin.
        emergency_gap_floor_m: that remaining distance is taken as at least this (no division by zero
            at or past the point).
        emergency_min_speed_mps: no emergency stop below this speed: the ordinary stop needs under
            4 cm at emergency_decel_mps2.
        emergency_close_m: an emergency stop holds while a constraint that may trigger one is within
            min_gap_m plus this of the front.
        emergency_clear_s: and is released after the shuttle has stood this long with none such.
        emergency_hold_moving_mps: only a constraint whose track moves faster than this holds an
            emergency stop; a standing obstacle is left to the restored state's own stop point, which
            keeps min_gap_m to it or holds the shuttle where it stands. Held for one, a shuttle whose
            merge out of S1's bay a snow phantom interrupted stood 468 s behind the car parked in the
            bay: standing, its path ran straight into the car (default service, snow, raw). 0.5 m/s:
            below the slowest walking speeds, above the jitter of a parked car's track (~0.2 m/s).
        crosswalk_clear_s: a shuttle standing for a crosswalk yield stays until the crosswalk has
            been clear this long (as ``emergency_clear_s``): a person making for the crossing right
            behind the one it yielded to is a confirmed radar track about 1.5 s later (seed 2: 1.5 s),
            and a restart caught by them stopped again 2 m on, from 1.4 m/s, with -1.6 m/s^2 and
            a 9.4 m/s^3 jerk as the wheels stopped. A yield whose settled track the tracker lost is held
            as long, moving or not, while its stop point is still a comfortable stop
            (``BehaviourStateMachine._crosswalk_hold``).
        standstill_mps: below this the shuttle counts as stopped (pull-over arrival, emergency release).
        entry_heading_back_m: an all-way stop entry's heading is the lanelet's heading this far before
            its end (the stop line is at the end; the last vertex has no heading of its own).
        stop_line_passed_m: an all-way stop line counts as still ahead until the front is this far past
            it (the shuttle stops stop_line_setback_m before it).
        stop_line_setback_m: the shuttle's front stops this far before an all-way stop line.
        stop_line_reach_m: the front within this of the line counts as at the line for the full stop.
        line_stopped_mps: below this speed the shuttle counts as stopped at the line.
        intersection_cleared_m: intersection handling ends when the front is this far past the stop
            line (past the campus junction's conflict box).
        platform_lane_probe_m: the lane's right edge at a stop is read this far into the platform.
        spot_stopping_decel_mps2: a re-chosen spot must be at least v^2 / (2 a) ahead of the front, a
            the comfortable deceleration (the fail-safe's minimal risk manoeuvre uses the same 1 m/s^2).
        spot_transition_share: the share of transition_m before the spot that must be free of bay
            obstacles (the lateral move enters the bay only in its second half).
        spot_extra_margin_m: clearance to a parked car before and behind the spot, beyond min_gap_m.
        spot_commit_m: the spot is fixed once the spot plus merge_room_m is this close ahead (WATonoBus
            scans 20 m ahead).
        spot_arrival_m: the front within this of the spot, stopped, counts as arrived.
        merged_max_offset_m: merging ends when the shuttle is within this of the lane centre ...
        merged_after_m: ... and has driven this far since the merge began.
        merge_hold_m: rear traffic holds the merge only while the shuttle is within this of where the
            merge began (once out in the lane it goes on).
        rear_half_width_m: road users more than this to either side of the route are not rear traffic
            (beyond the adjacent lane's centre).
        rear_too_close_m: moving rear traffic this close behind the shuttle's rear always holds the merge
            (standing traffic behind it waits for the shuttle: see ``stop_service.rear_blocker``).
        rear_min_closing_mps: rear traffic further back holds it only when closing at least this fast.
        traffic_lights: the traffic-light rule's parameters.
        passing: when a stationary obstacle blocking the lane is passed by the adjacent lane
            (:mod:`lastmile.decision.pass_rule`; off unless the planner can plan the pass).
        drop_off: a passenger's unscheduled drop-off (Snow Lion's button; :mod:`lastmile.decision.drop_off`).
        give_way: gap acceptance at give-way lines and after a two-way stop's full stop
            (:mod:`lastmile.decision.give_way_rule`).
    """

    cruise_speed_mps: float = 20.0 / 3.6
    merge_speed_mps: float = 3.0
    pullover_speed_mps: float = 3.5
    min_gap_m: float = 3.0
    corridor_margin_m: float = 0.5
    kerbside_margin_m: float = CURB_GAP_TARGET_M / 2.0
    kerbside_standing_mps: float = 1.0
    emergency_decel_mps2: float = 3.5
    stop_approach_m: float = 45.0
    intersection_approach_m: float = 35.0
    full_stop_s: float = 1.0
    unclaimed_turn_s: float = 4.0
    dwell_min_s: float = 6.0
    doorway_clear_s: float = 3.0
    rear_check_m: float = 60.0
    rear_tta_s: float = 7.0
    curb_gap_target_m: float = CURB_GAP_TARGET_M
    crosswalk_margin_m: float = 2.0
    crosswalk_lookahead_s: float = 6.0
    offroad_unknown_horizon_s: float = 6.0
    offroad_motion_window_s: float = 1.0
    unknown_settle_s: float = 1.0
    vehicle_prediction_horizon_s: float = 4.0
    cut_in_pass_margin_s: float = 2.0
    crosswalk_pass_margin_s: float = 2.0
    transition_m: float = 32.0
    merge_room_m: float = 4.0
    spot_scan_m: float = 40.0
    in_path_lookahead_m: float = 70.0
    vulnerable_horizon_s: float = 4.0
    vulnerable_reach_min_speed_mps: float = 1.0
    in_path_prediction_steps: int = 4
    behind_front_ignore_m: float = 1.0
    lead_decel_mps2: float = 3.0
    emergency_contact_margin_m: float = 0.5
    emergency_gap_floor_m: float = 0.05
    emergency_min_speed_mps: float = 0.5
    emergency_close_m: float = 2.0
    emergency_clear_s: float = 1.0
    emergency_hold_moving_mps: float = 0.5
    crosswalk_clear_s: float = 2.0
    standstill_mps: float = 0.05
    entry_heading_back_m: float = 0.1
    stop_line_passed_m: float = 0.5
    stop_line_setback_m: float = 0.5
    stop_line_reach_m: float = 3.0
    line_stopped_mps: float = 0.1
    intersection_cleared_m: float = 15.0
    platform_lane_probe_m: float = 1.0
    spot_stopping_decel_mps2: float = 1.0
    spot_transition_share: float = 0.5
    spot_extra_margin_m: float = 0.5
    spot_commit_m: float = 20.0
    spot_arrival_m: float = 0.6
    merged_max_offset_m: float = 0.3
    merged_after_m: float = 5.0
    merge_hold_m: float = 2.0
    rear_half_width_m: float = 2.5
    rear_too_close_m: float = 8.0
    rear_min_closing_mps: float = 0.5
    traffic_lights: TrafficLightRuleConfig = field(default_factory=TrafficLightRuleConfig)
    passing: PassConfig = field(default_factory=PassConfig)
    drop_off: DropOffConfig = field(default_factory=DropOffConfig)
    give_way: GiveWayConfig = field(default_factory=GiveWayConfig)

    def __post_init__(self) -> None:
        steps = self.in_path_prediction_steps
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ConfigError(
                f"DecisionConfig.in_path_prediction_steps: expected an integer >= 1, got {steps!r}"
            )
        # Divisors: a zero or negative value would divide by zero or turn a braking distance around.
        for name in (
            "lead_decel_mps2",
            "spot_stopping_decel_mps2",
            "emergency_gap_floor_m",
            "vulnerable_reach_min_speed_mps",
            "offroad_motion_window_s",
        ):
            value = getattr(self, name)
            if not value > 0:
                raise ConfigError(f"DecisionConfig.{name}: expected a positive number, got {value!r}")
        for name in (
            "kerbside_margin_m",
            "kerbside_standing_mps",
            "emergency_hold_moving_mps",
            "unknown_settle_s",
            "crosswalk_pass_margin_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"DecisionConfig.{name}: expected a finite value >= 0, got {value!r}")
        if self.kerbside_margin_m > self.corridor_margin_m:
            raise ConfigError(
                "DecisionConfig.kerbside_margin_m: expected at most corridor_margin_m "
                f"({self.corridor_margin_m} m), got {self.kerbside_margin_m} m"
            )
        h = self.offroad_unknown_horizon_s
        if not (math.isfinite(h) and h >= 0.0):
            raise ConfigError(
                f"DecisionConfig.offroad_unknown_horizon_s: expected a finite value >= 0 s, got {h!r}"
            )


@dataclass(frozen=True, slots=True)
class DecisionInput:
    """What the decision module sees each planning cycle (all from the stack's own estimates)."""

    stamp: Stamp
    map_from_base: SE2
    speed_mps: float
    route_s_m: float
    route_d_m: float
    tracks: TrackedObjects
    door_open: bool
    person_in_doorway: bool
    trajectory: Trajectory | None
    safety: SafetyDirective | None = None
    traffic_lights: TrafficLightStates | None = None
    predictions: PredictedPaths | None = None
    """Map-aware predicted paths of ``tracks`` (tracking's prediction), when the stack computes them."""
    accel_mps2: float = 0.0
    """The acceleration the stack last commanded: a stop's comfortable length grows with it
    (``traffic_light_rule.comfortable_stop_m``)."""
