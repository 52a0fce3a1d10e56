"""What the decision module is configured with and what it is given each planning cycle."""

from __future__ import annotations

from dataclasses import dataclass, field

from lastmile.core.geometry import SE2
from lastmile.core.objects import TrackedObjects
from lastmile.core.predictions import PredictedPaths
from lastmile.core.safety_messages import SafetyDirective
from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import TrafficLightStates
from lastmile.core.vehicle_messages import Trajectory
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig


@dataclass(frozen=True, slots=True, kw_only=True)
class DecisionConfig:
    """Parameters of the decision module (units in names).

    Attributes:
        cruise_speed_mps: reference speed in normal driving (WATonoBus: 20 km/h).
        merge_speed_mps: lower cap while merging, to be able to stop for anything from the rear.
        pullover_speed_mps: cap while entering the bay.
        min_gap_m: Delta s_min of eq. (2), the gap kept to a stopped obstacle.
        corridor_margin_m: lateral clearance added to half widths for the in-path test.
        emergency_decel_mps2: if stopping for an obstacle needs more than this, emergency stop.
        stop_approach_m: distance before a requested stop's platform at which pull-over begins.
        intersection_approach_m: distance before an all-way stop line at which intersection handling begins.
        full_stop_s: how long the shuttle stands at a stop line before it may go.
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
        vehicle_prediction_horizon_s: how far ahead a vehicle's lane-following predicted path
            (``DecisionInput.predictions``) is searched for where it enters the corridor (a car
            turning in from a side road); the shuttle then follows it from there
            (``decision.vehicle_cut_in``). 4 s: the look-ahead the in-path test gives pedestrians.
        cut_in_pass_margin_s: such a car is yielded to unless the shuttle's front would reach the
            entry at least this long before the car, or (a car crossing the lane) the car will have
            left the corridor at least this long before the front gets there.
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
    """

    cruise_speed_mps: float = 20.0 / 3.6
    merge_speed_mps: float = 3.0
    pullover_speed_mps: float = 3.5
    min_gap_m: float = 3.0
    corridor_margin_m: float = 0.5
    emergency_decel_mps2: float = 3.5
    stop_approach_m: float = 45.0
    intersection_approach_m: float = 35.0
    full_stop_s: float = 1.0
    dwell_min_s: float = 6.0
    doorway_clear_s: float = 3.0
    rear_check_m: float = 60.0
    rear_tta_s: float = 7.0
    curb_gap_target_m: float = 0.2
    crosswalk_margin_m: float = 2.0
    crosswalk_lookahead_s: float = 6.0
    vehicle_prediction_horizon_s: float = 4.0
    cut_in_pass_margin_s: float = 2.0
    transition_m: float = 32.0
    merge_room_m: float = 4.0
    spot_scan_m: float = 40.0
    traffic_lights: TrafficLightRuleConfig = field(default_factory=TrafficLightRuleConfig)


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
