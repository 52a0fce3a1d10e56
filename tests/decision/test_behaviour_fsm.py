"""The decision FSM on a straight test road: pull-over, onboarding, merging, crosswalk, emergency."""

import dataclasses

import numpy as np
import pytest

from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects, empty_tracks
from lastmile.core.predictions import PREDICTION_MODES
from lastmile.core.sensor_frames import StopCallFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourState, StopReason
from lastmile.decision.behaviour_fsm import BehaviourStateMachine
from lastmile.decision.decision_config import DecisionConfig, DecisionInput
from lastmile.decision.mission import MissionManager
from lastmile.decision.traffic_light_rule import comfortable_stop_m
from lastmile.tracking.prediction import MapAwarePredictor, PredictionConfig

G = VehicleGeometry()


def _fsm(layers) -> BehaviourStateMachine:
    mission = MissionManager(stop_order=("S1", "S2"))
    return BehaviourStateMachine(layers=layers, geometry=G, mission=mission)


def _tracks(rows: list[tuple[int, float, float, float, float, ObjectClass]]) -> TrackedObjects:
    table = []
    for _, x, y, vx, vy, cls in rows:
        row = [0.0] * len(TRACK_COLUMNS)
        row[0:6] = [
            x,
            y,
            vx,
            vy,
            4.5 if cls == ObjectClass.CAR else 0.5,
            1.8 if cls == ObjectClass.CAR else 0.5,
        ]
        row[7] = float(cls)
        table.append(row)
    return TrackedObjects(
        stamp=Stamp(0),
        ids=np.array([r[0] for r in rows], dtype=np.int64),
        table=np.array(table).reshape(-1, len(TRACK_COLUMNS)),
    )


def _inp(t_s, s_m, d_m=0.0, v=0.0, tracks=None, door=False, person=False, a=0.0):
    return DecisionInput(
        stamp=Stamp(int(t_s * 1e6)),
        map_from_base=SE2(s_m, d_m, 0.0),
        speed_mps=v,
        route_s_m=s_m,
        route_d_m=d_m,
        tracks=tracks if tracks is not None else empty_tracks(Stamp(0)),
        door_open=door,
        person_in_doorway=person,
        trajectory=None,
        accel_mps2=a,
    )


def test_without_requests_the_shuttle_drives_past_stops(straight_layers):
    fsm = _fsm(straight_layers)
    d = fsm.step(_inp(0.0, 170.0, v=5.0))
    assert d.state == BehaviourState.NORMAL_DRIVING and d.stop_at_s_m is None


def test_requested_stop_runs_pullover_onboarding_and_merging(straight_layers):
    fsm = _fsm(straight_layers)
    fsm.mission.on_call(StopCallFrame(stamp=Stamp(0), stop_id="S1", source="stop_button"))
    d = fsm.step(_inp(0.0, 170.0, v=5.0))
    assert d.state == BehaviourState.PULLOVER and d.pullover_spot is not None
    # The spot keeps the configured curb gap: centre line gap + half width left of the curb at d = -4.75.
    gap = fsm.config.curb_gap_target_m
    assert abs(d.pullover_spot.y_m - (-4.75 + gap + 1.0)) < 1e-9
    front = d.stop_at_s_m
    assert 204.6 <= front <= 224.0
    rear = front - G.front_from_rear_axle_m
    d = fsm.step(_inp(1.0, rear, d_m=-3.6, v=0.0))
    assert d.state == BehaviourState.ONBOARDING
    d = fsm.step(_inp(2.0, rear, d_m=-3.6))
    assert d.door_open
    t = 2.0
    for k in range(40):  # door open, a rider in the doorway for the first 5 s
        t += 0.5
        d = fsm.step(_inp(t, rear, d_m=-3.6, door=True, person=k < 10))
    assert d.state == BehaviourState.ONBOARDING and not d.door_open  # closing after the doorway cleared
    assert t - 2.0 >= 6.0
    d = fsm.step(_inp(t + 0.5, rear, d_m=-3.6, door=False))
    assert d.state == BehaviourState.MERGING
    assert not fsm.mission.wants("S1")
    # A car approaching in the lane from behind holds the shuttle in the bay.
    car = _tracks([(5, rear - 30.0, 0.0, 5.0, 0.0, ObjectClass.CAR)])
    d = fsm.step(_inp(t + 1.0, rear, d_m=-3.6, tracks=car))
    assert "rear" in d.reason and d.stop_at_s_m is not None
    d = fsm.step(_inp(t + 2.0, rear, d_m=-3.6))
    assert d.reason == "merging"


def test_pedestrian_on_the_crosswalk_makes_the_shuttle_yield_before_it(straight_layers):
    fsm = _fsm(straight_layers)
    ped = _tracks([(3, 100.0, 1.0, 0.0, 1.2, ObjectClass.PEDESTRIAN)])
    d = fsm.step(_inp(0.0, 60.0, v=5.0, tracks=ped))
    assert d.stop_at_s_m is not None and d.stop_at_s_m <= 98.0
    assert d.state == BehaviourState.NORMAL_DRIVING
    # Standing on the crossing: the crosswalk's point binds, short of where the in-path rule keeps.
    assert d.stop_reason is StopReason.CROSSWALK
    # Close, the same person still orders the emergency stop (the in-path point may, a rule's not).
    d = _fsm(straight_layers).step(_inp(0.0, 92.0, v=5.0, tracks=ped))
    assert d.state == BehaviourState.EMERGENCY_STOP and d.risk_track_id == 3


def _held_for_the_clear_time_then_released(fsm: BehaviourStateMachine, s_m: list[float], v: list[float]):
    """Yield to a person on the crossing at s_m[0], then lose their track: the stop point holds until
    ``crosswalk_clear_s`` has passed (at s_m[1] after 0.5 s, s_m[2] just before, s_m[3] just after)."""
    ped = _tracks([(3, 100.0, 1.0, 0.0, 1.2, ObjectClass.PEDESTRIAN)])
    d = fsm.step(_inp(0.0, s_m[0], v=v[0], tracks=ped))
    stop = d.stop_at_s_m
    assert stop is not None and d.stop_reason is StopReason.CROSSWALK
    clear = fsm.config.crosswalk_clear_s
    for t, s, speed in ((0.5, s_m[1], v[1]), (clear - 0.1, s_m[2], v[2])):
        d = fsm.step(_inp(t, s, v=speed))  # gone, not seen to leave: still held
        assert d.stop_at_s_m == stop and d.stop_reason is StopReason.CROSSWALK and d.risk_track_id == 3
    d = fsm.step(_inp(clear + 0.1, s_m[3], v=v[3]))  # not back within crosswalk_clear_s: released
    assert d.stop_at_s_m is None


def test_a_shuttle_standing_for_a_crosswalk_waits_until_it_has_been_clear_for_a_while(straight_layers):
    # Seed 2: the shuttle restarted the moment the person it yielded to left the crossing, and the
    # next person, a confirmed track 1.5 s later, stopped it again 2 m on with a 9.4 m/s^3 jerk.
    _held_for_the_clear_time_then_released(_fsm(straight_layers), [80.0] * 4, [0.0] * 4)
    # One that yields while moving (it would have braked, not stood) holds nothing once clear: the
    # person is still tracked, walking away beyond the crossing.
    moving = _fsm(straight_layers)
    ped = _tracks([(3, 100.0, 1.0, 0.0, 1.2, ObjectClass.PEDESTRIAN)])
    assert moving.step(_inp(0.0, 60.0, v=5.0, tracks=ped)).stop_at_s_m is not None
    away = _tracks([(3, 100.0, 12.0, 0.0, 1.2, ObjectClass.PEDESTRIAN)])
    assert moving.step(_inp(0.1, 60.5, v=5.0, tracks=away)).stop_at_s_m is None


def test_a_crosswalk_yield_whose_track_is_lost_while_braking_is_held_for_a_while(straight_layers):
    # Clear seed 1 (a_nom 1.0): the person beside the crossing went missing from the tracks for 0.5 s
    # while the shuttle braked for them at 1.6 m/s; released, it drove on, and their return 1.1 m
    # before the stop point ended the stop with 0.5 m/s^2 of braking left (+3.57 m/s^3).
    _held_for_the_clear_time_then_released(
        _fsm(straight_layers), [89.0, 89.7, 90.3, 90.4], [1.6, 1.1, 0.4, 0.3]
    )
    # Not held past a comfortable stop: lost at 5 m/s with 2 m left (6.25 m/s^2 to stop there).
    fsm = _fsm(straight_layers)
    ped = _tracks([(3, 100.0, 1.0, 0.0, 1.2, ObjectClass.PEDESTRIAN)])
    assert fsm.step(_inp(0.0, 80.0, v=5.0, tracks=ped)).stop_at_s_m is not None
    assert fsm.step(_inp(0.1, 89.0, v=5.0)).stop_at_s_m is None


def test_a_lost_snow_echo_does_not_hold_a_crosswalk_yield(straight_layers):
    # Snow seed 3: an unclassified track 0.4-0.6 s old made the crosswalk rule yield 13 m ahead at
    # 5.4 m/s; lost and held, it braked the shuttle to -2.9 m/s^2. A new unclassified track is not
    # held once lost (``unknown_settle_s``); the same track, settled, is.
    echo = _tracks([(3, 100.0, 1.0, 0.0, 1.2, ObjectClass.UNKNOWN)])
    fsm = _fsm(straight_layers)
    assert fsm.step(_inp(0.0, 80.0, v=5.0, tracks=_aged(echo, 0.5))).stop_at_s_m is not None
    assert fsm.step(_inp(0.1, 80.5, v=5.0)).stop_at_s_m is None
    fsm = _fsm(straight_layers)
    assert fsm.step(_inp(0.0, 80.0, v=5.0, tracks=_aged(echo, 2.0))).stop_at_s_m is not None
    assert fsm.step(_inp(0.1, 80.5, v=5.0)).stop_at_s_m is not None


def test_pedestrian_walking_to_the_crosswalk_is_yielded_to_before_reaching_the_kerb(straight_layers):
    # 4.75 m beyond the crosswalk's end, walking towards it at 1.3 m/s: at the kerb zone in about 2 s,
    # on the lane in about 4 s, when a shuttle 24 m away at 5.5 m/s would be on the crossing.
    walking_in = _tracks([(3, 100.0, 10.0, 0.0, -1.3, ObjectClass.PEDESTRIAN)])
    d = _fsm(straight_layers).step(_inp(0.0, 70.0, v=5.5, tracks=walking_in))
    assert d.stop_at_s_m is not None and d.stop_at_s_m <= 98.0
    assert d.stop_reason is StopReason.CROSSWALK  # the cause, typed, for the fleet, HMI and reports
    # The same person walking away, or standing back from the kerb, is not crossing.
    for vy in (1.3, 0.0):
        other = _tracks([(3, 100.0, 10.0, 0.0, vy, ObjectClass.PEDESTRIAN)])
        d = _fsm(straight_layers).step(_inp(0.0, 70.0, v=5.5, tracks=other))
        assert d.stop_at_s_m is None


def _aged(tracks: TrackedObjects, age_s: float) -> TrackedObjects:
    table = tracks.table.copy()
    table[:, TRACK_COLUMNS.index("age_s")] = age_s
    return TrackedObjects(stamp=tracks.stamp, ids=tracks.ids, table=table)


def test_a_crosswalk_brakes_hard_for_an_unclassified_track_only_once_it_has_settled(straight_layers):
    # Snow, raw: a 0.8 m unknown track 0.3-0.9 s old, keeping pace beside the shuttle, made the
    # crosswalk rule brake at the urgent rate (-2.8 m/s^2) with no road user within 15 m.
    settle = DecisionConfig().unknown_settle_s
    # On the crossing's marking over the sidewalk (x 98..102), drifting towards the lane.
    on_it = _tracks([(3, 100.0, 3.0, 0.0, -0.3, ObjectClass.UNKNOWN)])

    def decide(rear_s: float, age_s: float, tracks: TrackedObjects = on_it):
        return _fsm(straight_layers).step(_inp(0.0, rear_s, v=5.0, tracks=_aged(tracks, age_s)))

    # Far enough off to stop comfortably: yielded to at once, new or not.
    for age in (0.0, 0.5 * settle, settle):
        assert decide(60.0, age).stop_reason is StopReason.CROSSWALK
    # Too close for a comfortable stop: not for a new one, yes for one tracked a while.
    close = 97.0 - G.front_from_rear_axle_m - 0.8 * comfortable_stop_m(5.0, DecisionConfig().traffic_lights)
    assert decide(close, 0.5 * settle).stop_at_s_m is None
    assert decide(close, settle).stop_reason is StopReason.CROSSWALK
    # A pedestrian counts from its birth; and a new unknown in the path is still the in-path rule's.
    ped = _tracks([(3, 100.0, 3.0, 0.0, -0.3, ObjectClass.PEDESTRIAN)])
    assert decide(close, 0.0, ped).stop_reason is StopReason.CROSSWALK
    in_lane = _tracks([(4, 90.0, 0.0, 0.0, 0.0, ObjectClass.UNKNOWN)])
    d = decide(60.0, 0.0, in_lane)
    assert d.stop_reason is StopReason.OBSTACLE and d.risk_track_id == 4


def test_a_pedestrian_whose_class_flickers_to_unknown_is_still_yielded_to(straight_layers):
    # Clear seed 4 (a_nom 1.0): a person yielded to from 13 m at 5.5 m/s read as unclassified for a
    # few sweeps at 0.7 s old; taken for a new unclassified track, the yield was dropped as no longer
    # comfortable and came back 0.3 s later as an urgent stop (-2.28 m/s^2, +18 m/s^3 at its end).
    settle = DecisionConfig().unknown_settle_s
    on_it = [(3, 100.0, 3.0, 0.0, -0.3, ObjectClass.PEDESTRIAN)]
    flicker = [(3, 100.0, 3.0, 0.0, -0.3, ObjectClass.UNKNOWN)]
    close = 97.0 - G.front_from_rear_axle_m - 0.8 * comfortable_stop_m(5.0, DecisionConfig().traffic_lights)
    fsm = _fsm(straight_layers)
    d = fsm.step(_inp(0.0, close - 1.0, v=5.0, tracks=_aged(_tracks(on_it), 0.4 * settle)))
    assert d.stop_reason is StopReason.CROSSWALK
    d = fsm.step(_inp(0.1, close, v=5.0, tracks=_aged(_tracks(flicker), 0.5 * settle)))
    assert d.stop_reason is StopReason.CROSSWALK and d.risk_track_id == 3
    # A new unclassified track with that id after the person's track ended is new again.
    fsm.step(_inp(0.2, close, v=5.0))
    assert fsm.step(_inp(0.3, close, v=5.0, tracks=_aged(_tracks(flicker), 0.0))).stop_at_s_m is None


def test_a_shuttle_moving_off_past_the_line_stops_at_the_crossings_edge(straight_layers):
    # Snow seed 2 (a_nom 1.0): moving off after a yield, the front 0.7 m past the line, a person first
    # tracked as unclassified was ignored at 0.2 m/s (the line behind: no comfortable stop "before" it)
    # and settled at 0.9 m/s; the stop point, the line behind the front, was an overshoot braked for at
    # -2.76 m/s^3.
    front = 97.7  # the line is at 97.0, the crossing from 98.0
    walking_in = [(3, 100.0, 6.0, 0.0, -1.2, ObjectClass.UNKNOWN)]
    for age in (0.0, 2.0):  # new, or tracked a while: a comfortable stop fits before the crossing
        d = _fsm(straight_layers).step(
            _inp(0.0, front - G.front_from_rear_axle_m, v=0.2, tracks=_aged(_tracks(walking_in), age))
        )
        assert d.stop_reason is StopReason.CROSSWALK and d.risk_track_id == 3
        assert d.stop_at_s_m == pytest.approx(98.0)
    # Too fast to stop before the crossing comfortably: as before, a new track is not yielded to, a
    # settled one at the line; standing, the line keeps the shuttle where it stands.
    for v, age, stop in ((0.9, 0.0, None), (0.9, 2.0, 97.0), (0.0, 2.0, 97.0)):
        d = _fsm(straight_layers).step(
            _inp(0.0, front - G.front_from_rear_axle_m, v=v, tracks=_aged(_tracks(walking_in), age))
        )
        assert d.stop_at_s_m == (None if stop is None else pytest.approx(stop))


def test_a_yield_no_comfortable_stop_fits_is_not_made_for_someone_reaching_the_path_after_the_shuttle(
    straight_layers,
):
    # Clear seed 4 (a_nom 1.0): a person appeared 4 m from the kerb, 8 m from the path, as the front
    # came within 10 m of the line at 5.5 m/s; the yield braked at -2.28 m/s^2 (+18 m/s^3 at its
    # end), and they would have reached the path 2.5 s after the shuttle had cleared the crossing.
    rear = 97.0 - 9.8 - G.front_from_rear_axle_m

    def walker(y_m: float) -> TrackedObjects:
        return _tracks([(3, 100.0, y_m, 0.0, -1.3, ObjectClass.PEDESTRIAN)])

    assert _fsm(straight_layers).step(_inp(0.0, rear, v=5.5, tracks=walker(9.5))).stop_at_s_m is None
    # Nearer the path they would be in it before the shuttle is through: yielded to, hard or not.
    d = _fsm(straight_layers).step(_inp(0.0, rear, v=5.5, tracks=walker(7.5)))
    assert d.stop_reason is StopReason.CROSSWALK
    # Far enough off for a comfortable stop, the shuttle yields to the first one as well,
    far = _fsm(straight_layers)
    assert far.step(_inp(0.0, rear - 10.0, v=5.5, tracks=walker(11.3))).stop_reason is StopReason.CROSSWALK
    # and a yield under way is kept, comfortable or not.
    assert far.step(_inp(0.1, rear, v=5.5, tracks=walker(9.5))).stop_reason is StopReason.CROSSWALK


def test_a_shuttle_moving_past_the_line_passes_first_too(straight_layers):
    # Clear seed 4 (a_nom 1.0): at 5.5 m/s the pass-first judgement held while the line was ahead; with
    # the front 0.6 m past it (the line is 1 m before the crossing) it no longer applied, and the
    # shuttle braked for the line behind its front for 0.3 s (-2.42 m/s^3) before it was on the crossing.
    rear = 97.0 + 0.6 - G.front_from_rear_axle_m

    def walker(y_m: float) -> TrackedObjects:
        return _tracks([(3, 100.0, y_m, 0.0, -1.3, ObjectClass.PEDESTRIAN)])

    # 8 m off the path at 1.3 m/s: about the crossing within the 1.6 s to clear it, in the corridor
    # 2.9 s after the shuttle has cleared it.
    assert _fsm(straight_layers).step(_inp(0.0, rear, v=5.5, tracks=walker(8.0))).stop_at_s_m is None
    # Someone who is in the path before the shuttle is through is still yielded to,
    d = _fsm(straight_layers).step(_inp(0.0, rear, v=5.5, tracks=walker(4.0)))
    assert d.stop_reason is StopReason.CROSSWALK
    # and a shuttle creeping off past the line after a yield still stops for the person it yielded to.
    d = _fsm(straight_layers).step(_inp(0.0, rear, v=0.5, tracks=walker(8.0)))
    assert d.stop_reason is StopReason.CROSSWALK


def test_obstacle_too_close_to_stop_comfortably_triggers_emergency_stop(straight_layers):
    fsm = _fsm(straight_layers)
    # Front bumper at 53.75 m, goose 3 m ahead of it: stopping would need over 6 m/s^2.
    goose = _tracks([(4, 57.0, 0.0, 0.0, 0.0, ObjectClass.ANIMAL)])
    d = fsm.step(_inp(0.0, 50.0, v=5.5, tracks=goose))
    assert d.state == BehaviourState.EMERGENCY_STOP and d.risk_track_id == 4
    assert d.stop_reason is StopReason.EMERGENCY
    d = fsm.step(_inp(1.0, 51.0, v=0.0, tracks=goose))
    assert d.state == BehaviourState.EMERGENCY_STOP  # still blocked
    empty = _tracks([])
    fsm.step(_inp(2.0, 51.0, v=0.0, tracks=empty))
    d = fsm.step(_inp(3.5, 51.0, v=0.0, tracks=empty))
    assert d.state == BehaviourState.NORMAL_DRIVING


def test_an_emergency_stop_holds_for_what_moves_close_and_hands_a_standing_obstacle_back(straight_layers):
    """Standing, the shuttle leaves the emergency stop with only a standing obstacle close: the restored
    state stops for it (the point stays behind the front, so the shuttle stays put). Held for it, a
    shuttle whose merge a snow phantom interrupted stood for good behind the car parked in the bay."""
    clear_s = DecisionConfig().emergency_clear_s
    # A goose 3 m ahead brings the emergency stop, then stands there.
    standing = _tracks([(4, 57.0, 0.0, 0.0, 0.0, ObjectClass.ANIMAL)])
    fsm = _fsm(straight_layers)
    assert fsm.step(_inp(0.0, 50.0, v=5.5, tracks=standing)).state == BehaviourState.EMERGENCY_STOP
    fsm.step(_inp(1.0, 51.0, v=0.0, tracks=standing))
    assert fsm.step(_inp(1.0 + clear_s + 0.1, 51.0, v=0.0, tracks=standing)).state == (
        BehaviourState.NORMAL_DRIVING
    )  # released; this cycle still holds still, the next plans from the restored state
    d = fsm.step(_inp(1.2 + clear_s, 51.0, v=0.0, tracks=standing))
    assert d.state == BehaviourState.NORMAL_DRIVING and d.risk_track_id == 4
    assert d.stop_reason is StopReason.OBSTACLE and d.stop_at_s_m <= 51.0 + G.front_from_rear_axle_m
    # The same goose walking about 3 m ahead (0.6 m/s across the lane) keeps it.
    walking = _tracks([(4, 57.0, 0.0, 0.0, 0.6, ObjectClass.ANIMAL)])
    fsm = _fsm(straight_layers)
    assert fsm.step(_inp(0.0, 50.0, v=5.5, tracks=walking)).state == BehaviourState.EMERGENCY_STOP
    for t_s in (1.0, 1.0 + clear_s + 0.1, 2.0 + 2.0 * clear_s):
        d = fsm.step(_inp(t_s, 51.0, v=0.0, tracks=walking))
        assert d.state == BehaviourState.EMERGENCY_STOP and d.risk_track_id == 4


def test_distant_goose_in_lane_is_a_normal_stop_not_an_emergency(straight_layers):
    fsm = _fsm(straight_layers)
    goose = _tracks([(4, 90.0, 0.5, 0.0, 0.0, ObjectClass.ANIMAL)])
    d = fsm.step(_inp(0.0, 50.0, v=5.5, tracks=goose))
    assert d.state == BehaviourState.NORMAL_DRIVING
    assert d.risk_track_id == 4 and d.stop_at_s_m < 90.0
    assert d.stop_reason is StopReason.OBSTACLE


def test_a_slow_pedestrian_the_map_sends_to_the_crosswalk_is_yielded_to(straight_layers):
    # Dawdling towards the crossing at 0.3 m/s from 10 m beside the road: at that pace the constant-
    # velocity path stays short of the kerb zone, but someone making for a crossing speeds up to cross.
    dawdler = _tracks([(3, 100.0, 10.0, 0.0, -0.3, ObjectClass.PEDESTRIAN)])
    d = _fsm(straight_layers).step(_inp(0.0, 70.0, v=5.5, tracks=dawdler))
    assert d.stop_at_s_m is None  # constant velocity alone does not reach the zone
    paths = MapAwarePredictor(straight_layers.hdmap, PredictionConfig(horizon_s=6.0)).predict_objects(dawdler)
    assert PREDICTION_MODES[int(paths.mode[0])] == "to_crosswalk"
    with_paths = dataclasses.replace(_inp(0.0, 70.0, v=5.5, tracks=dawdler), predictions=paths)
    d = _fsm(straight_layers).step(with_paths)
    assert d.stop_at_s_m is not None and d.stop_at_s_m <= 98.0
    # Walking away from the road, the map does not send them to the crossing: no stop.
    leaving = _tracks([(3, 100.0, 10.0, 0.0, 0.3, ObjectClass.PEDESTRIAN)])
    paths = MapAwarePredictor(straight_layers.hdmap, PredictionConfig(horizon_s=6.0)).predict_objects(leaving)
    d = _fsm(straight_layers).step(
        dataclasses.replace(_inp(0.0, 70.0, v=5.5, tracks=leaving), predictions=paths)
    )
    assert d.stop_at_s_m is None


def test_the_crosswalk_stop_is_where_the_pedestrian_in_the_path_will_keep_the_shuttle(straight_layers):
    # Walking across at 1.3 m/s, 7 m beside the lane, then in it: the stop point the shuttle is braking
    # for must not move nearer as they step in (it did by ~0.5 m, late in a stop at ~1 m/s).
    approaching = _tracks([(3, 100.0, 7.0, 0.0, -1.3, ObjectClass.PEDESTRIAN)])
    before = _fsm(straight_layers).step(_inp(0.0, 85.0, v=1.0, tracks=approaching))
    assert before.stop_reason is StopReason.CROSSWALK and before.stop_at_s_m is not None
    in_lane = _tracks([(3, 100.0, 0.0, 0.0, -1.3, ObjectClass.PEDESTRIAN)])
    after = _fsm(straight_layers).step(_inp(0.0, 85.0, v=1.0, tracks=in_lane))
    assert after.stop_at_s_m is not None and after.risk_track_id == 3
    assert before.stop_at_s_m <= after.stop_at_s_m + 1e-9
    # Past that point (restarting after a yield when someone else steps up): back to the line ahead,
    # never a stop point behind the front.
    front_from_rear = VehicleGeometry().front_from_rear_axle_m
    rear = before.stop_at_s_m - front_from_rear + 0.3
    again = _fsm(straight_layers).step(_inp(0.0, rear, v=1.0, tracks=approaching))
    assert again.stop_reason is StopReason.CROSSWALK and again.stop_at_s_m is not None
    assert again.stop_at_s_m > rear + front_from_rear


def test_a_standing_post_the_filter_reads_as_walking_to_a_crosswalk_is_not_yielded_to(straight_layers):
    # Snow seed 0 (a_nom 1.0): a 0.6 x 0.2 m unclassified track beside a crosswalk, 9 s old, read
    # 0.67 m/s towards the road while its positions had barely moved; yielded to 10 m ahead at
    # 5.5 m/s, and released 0.3 s later when it was lost (-2.12 m/s^3).
    def post(vy_mps: float, y_m: float) -> TrackedObjects:
        table = _tracks([(3, 97.0, y_m, 0.0, vy_mps, ObjectClass.UNKNOWN)]).table.copy()
        table[:, TRACK_COLUMNS.index("age_s")] = 9.0
        return TrackedObjects(stamp=Stamp(0), ids=np.array([3]), table=table)

    rear = 90.0 - G.front_from_rear_axle_m
    # First published 8.5 s earlier at the same place, as the post was (the filter's velocity then
    # pointed away from the road).
    fsm = _fsm(straight_layers)
    fsm.step(_inp(0.0, 40.0, v=5.5, tracks=post(0.3, 3.3)))
    d = fsm.step(_inp(8.5, rear, v=5.5, tracks=post(-0.6, 3.25)))
    assert d.stop_at_s_m is None
    # The same track having walked 4.75 m towards the road in that time is yielded to.
    fsm = _fsm(straight_layers)
    fsm.step(_inp(0.0, 40.0, v=5.5, tracks=post(-0.6, 8.0)))
    d = fsm.step(_inp(8.5, rear, v=5.5, tracks=post(-0.6, 3.25)))
    assert d.stop_reason is StopReason.CROSSWALK


def test_a_yield_under_way_past_the_line_keeps_its_point_and_its_new_track(straight_layers):
    # Snow seed 2 (a_nom 1.0): moving off at 0.2 m/s past the line, the shuttle yielded at the
    # crossing's edge to a person first tracked as unclassified; 0.2 s later, at 0.4 m/s, no
    # comfortable stop fitted before the edge and the new track was dropped; settled 0.5 s later it
    # came back with the line behind the front as its stop, braked for at -2.76 m/s^3.
    def person(y_m: float, age_s: float) -> TrackedObjects:
        return _aged(_tracks([(3, 99.0, y_m, 0.0, 1.24, ObjectClass.UNKNOWN)]), age_s)

    front = G.front_from_rear_axle_m
    fsm = _fsm(straight_layers)
    d = fsm.step(_inp(0.0, 97.3 - front, v=0.25, tracks=person(-6.4, 0.3)))
    assert d.stop_reason is StopReason.CROSSWALK and d.stop_at_s_m == 98.0  # the crossing's edge
    d = fsm.step(_inp(0.2, 97.85 - front, v=0.45, tracks=person(-6.15, 0.5)))
    assert d.stop_reason is StopReason.CROSSWALK and d.stop_at_s_m == 98.0  # kept, not dropped
    d = fsm.step(_inp(0.7, 98.05 - front, v=0.3, tracks=person(-5.5, 1.0)))
    assert d.stop_reason is StopReason.CROSSWALK and d.stop_at_s_m == 98.0  # not the line behind
