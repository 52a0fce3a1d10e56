"""Snow Lion's seat-button drop-off: the safe-place search, the wait and the pedestrian check, the FSM.

The straight test road (``tests/conftest.py``): a 400 m lane, kerb at d = -1.75, a crosswalk at
s 98-102, bus stops S1 (200-224) and S2 (300-324) in bays (kerb at -4.75 over their platforms).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.sensor_frames import DropOffRequestFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourState, StopReason
from lastmile.decision.behaviour_fsm import BehaviourStateMachine
from lastmile.decision.behaviour_memory import DecisionContext
from lastmile.decision.decision_config import DecisionConfig
from lastmile.decision.drop_off import DropOffPlaces, pedestrian_near_door
from lastmile.decision.drop_off_config import DropOffConfig
from lastmile.decision.mission import MissionManager
from lastmile.hdmap.layers import DRIVEWAY, INTERSECTION, RouteStopLine, SLayerDatabase
from lastmile.hdmap.model import StopLine
from tests.decision.test_behaviour_fsm import G, _fsm, _inp, _tracks

C = DecisionConfig()
D = DropOffConfig()
FRONT = G.front_from_rear_axle_m


def _ctx(layers: SLayerDatabase) -> DecisionContext:
    mission = MissionManager(stop_order=tuple(rs.stop.id for rs in layers.stops))
    return DecisionContext(layers=layers, geometry=G, mission=mission, config=C, route=layers.centerline)


def _find(layers: SLayerDatabase, front_s: float, earliest: float = 32.0, limit: float = 90.0, obstacles=()):
    places = DropOffPlaces(layers, D)
    return places.find(_ctx(layers), front_s, earliest, limit, list(obstacles))


def _body_m(spot_front_s: float) -> tuple[float, float]:
    return spot_front_s - G.length_m, spot_front_s


# --- where it may stop --------------------------------------------------------------------------
def test_the_kerb_beside_a_crosswalk_and_a_bus_stop_is_no_place_to_stop(straight_layers) -> None:
    ok = DropOffPlaces(straight_layers, D).allowed
    s = straight_layers.s_m
    assert not ok[(s >= 98 - 5) & (s <= 102 + 5)].any(), "on a crosswalk or within 5 m of it"
    assert not ok[(s >= 200) & (s <= 224)].any() and not ok[(s >= 300) & (s <= 324)].any(), "bus stops"
    assert ok[(s >= 110) & (s <= 190)].all() and ok[(s >= 10) & (s <= 90)].all(), "plain kerbside road"


def test_junctions_stop_lines_and_sharp_bends_are_no_places_to_stop(straight_layers) -> None:
    road = straight_layers.road_type.copy()
    road[150:160] = INTERSECTION
    road[60:66] = DRIVEWAY
    line = RouteStopLine(
        stop_line=StopLine(id=1, line=np.array([[150.0, -1.75], [150.0, 0.0]]), lanelet_id=1),
        s_m=150.0,
        all_way_stop_id=1,
    )
    layers = dataclasses.replace(straight_layers, road_type=road, stop_lines=(line,))
    ok = DropOffPlaces(layers, D).allowed
    s = layers.s_m
    assert not ok[(s >= 150 - 10) & (s <= 160 + 5)].any(), "10 m before the line, the box, 5 m after it"
    assert not ok[(s >= 60 - 5) & (s <= 66 + 5)].any(), "a driveway's mouth and 5 m either side"
    assert ok[(s >= 175) & (s <= 195)].all()
    # A 40 m radius bend (the campus corners) is sharp; the same road straight is not.
    sharp = dataclasses.replace(D, max_curvature_1pm=1.0 / 1000.0)
    assert DropOffPlaces(straight_layers, sharp).allowed[150]  # a straight road passes any limit
    arc = np.linspace(0.0, math.pi / 2.0, 64)
    bend = np.c_[40.0 * np.sin(arc), 40.0 * (1.0 - np.cos(arc))]
    assert not _allowed_on(bend, straight_layers).any()


def _allowed_on(xy: np.ndarray, template: SLayerDatabase) -> np.ndarray:
    from lastmile.core.polyline import Polyline

    line = Polyline(xy)
    n = int(line.length_m)
    layers = SLayerDatabase(
        hdmap=template.hdmap,
        centerline=line,
        step_m=1.0,
        s_m=np.arange(n, dtype=float),
        speed_limit_mps=np.full(n, 5.0),
        lane_left_d_m=np.full(n, 1.75),
        lane_right_d_m=np.full(n, -1.75),
        curb_right_d_m=np.full(n, -1.75),
        road_type=np.zeros(n, dtype=np.int8),
    )
    return DropOffPlaces(layers, D).allowed[5:-5]


def test_picks_the_first_good_kerb_beyond_the_stopping_distance(straight_layers) -> None:
    # From s 60 the first 32 m reach the crosswalk's keep-out (93-107): the spot is past it.
    found = _find(straight_layers, 60.0)
    assert found is not None
    spot, curb = found
    rear, _ = _body_m(spot)
    # The keep-out ends at 107; its record [107, 108) is out, so the body starts at 108 at the latest.
    assert 107.0 - 1e-9 <= rear <= 108.0 + 1e-9 and curb == -1.75, rear
    # From s 10 the kerb before the crosswalk is long enough: the spot is the earliest one.
    spot2, _ = _find(straight_layers, 10.0)
    assert spot2 == pytest.approx(10.0 + 32.0, abs=1e-6)
    assert spot2 + C.merge_room_m <= 93.0


def test_a_car_parked_at_the_kerb_moves_the_spot_beyond_it(straight_layers) -> None:
    from lastmile.core.route_obstacles import route_obstacles

    rear_s = 110.0 - FRONT
    parked = _tracks([(5, 150.0, -0.8, 0.0, 0.0, ObjectClass.CAR)])
    obstacles = route_obstacles(parked, straight_layers.centerline, rear_s, FRONT)
    free, _ = _find(straight_layers, 110.0, obstacles=())
    spot, _ = _find(straight_layers, 110.0, obstacles=obstacles)
    assert free == pytest.approx(142.0)
    margin = C.min_gap_m + C.spot_extra_margin_m
    assert spot - G.length_m >= 150.0 + 2.25 + margin - 1e-6, "behind the car with the stop's margin"
    # On the sidewalk beyond the kerb, a pedestrian blocks nothing.
    walker = _tracks([(6, 142.0, -3.0, 0.0, 0.0, ObjectClass.PEDESTRIAN)])
    obstacles = route_obstacles(walker, straight_layers.centerline, rear_s, FRONT)
    assert _find(straight_layers, 110.0, obstacles=obstacles)[0] == pytest.approx(142.0)


def test_no_place_on_a_kerb_too_short_for_the_shuttle(straight_layers) -> None:
    road = straight_layers.road_type.copy()
    # Kerb stretches between driveways: 108-118 (10 m) is shorter than body and merge room with the
    # 5 m clearances; 118 + 5 + ... 150 on is long.
    road[113:114] = DRIVEWAY
    road[130:131] = DRIVEWAY
    layers = dataclasses.replace(straight_layers, road_type=road)
    spot, _ = _find(layers, 70.0, earliest=32.0, limit=120.0)
    assert spot - G.length_m >= 131.0 + 5.0 - 1e-9, spot
    assert _find(layers, 70.0, earliest=32.0, limit=60.0) is None


def test_the_search_ends_at_the_next_stop(straight_layers) -> None:
    """From s 165 the next stop (S1) begins 35 m ahead: nothing fits before it; the FSM asks for S1,
    whose door cycle serves the drop-off."""
    fsm = _fsm(straight_layers)
    fsm.mission.on_drop_off(DropOffRequestFrame(stamp=Stamp(0)))
    d = fsm.step(_inp(0.0, 165.0 - FRONT, v=5.0))
    assert d.state == BehaviourState.NORMAL_DRIVING
    assert "S1" in fsm.mission.requested and fsm.memory.drop_off.deferred_stop_id == "S1"
    assert "drop-off at stop S1" in d.reason
    d = fsm.step(_inp(0.1, 166.0 - FRONT, v=5.0))
    assert d.state == BehaviourState.PULLOVER and fsm.memory.stop.stop_index == 0
    assert "drop-off: no safe place to stop before it" in fsm.transitions[-1][3]
    assert d.stop_reason == StopReason.BUS_STOP and d.stop_at_s_m is not None
    rear = d.stop_at_s_m - FRONT
    d = fsm.step(_inp(10.0, rear, v=0.0))
    assert d.state == BehaviourState.ONBOARDING
    _door_cycle(fsm, 10.0, rear)
    assert fsm.state == BehaviourState.MERGING
    assert fsm.mission.drop_offs_served == 1 and not fsm.mission.drop_off_pending


def _door_cycle(fsm, t: float, s: float) -> float:
    """Door opens, a rider steps out, the doorway clears, the door closes; returns the time after."""
    for dt, door, person in ((0.0, True, True), (2.5, True, False), (9.0, True, False), (9.1, False, False)):
        fsm.step(_inp(t + dt, s, door=door, person=person))
    return t + 9.1


# --- the wait and the pedestrian check ------------------------------------------------------------
def test_pedestrian_near_door_looks_at_the_door_side_within_the_radius() -> None:
    pose = SE2(100.0, 0.0, 0.0)

    def near(x: float, y: float, cls=ObjectClass.PEDESTRIAN):
        return pedestrian_near_door(_tracks([(3, x, y, 0.0, 0.0, cls)]), pose, G, D.clear_radius_m)

    assert near(101.5, -2.5) == (3, pytest.approx(1.25))  # beside the door: 1.5 m out, less its radius
    assert near(106.0, -2.0) is not None  # ahead of the front on the kerb side
    assert near(101.5, 2.5) is None  # the far side
    assert near(101.5, -5.0) is None  # beyond 3 m
    assert near(101.5, -2.5, ObjectClass.UNKNOWN) is None  # a pole or a bin is no pedestrian
    assert near(101.5, -2.5, ObjectClass.CYCLIST) is not None


def test_drop_off_halts_at_the_kerb_waits_8_s_and_for_the_pedestrian_then_merges(straight_layers) -> None:
    fsm = _fsm(straight_layers)
    fsm.mission.on_drop_off(DropOffRequestFrame(stamp=Stamp(0)))
    d = fsm.step(_inp(0.0, 10.0, v=5.0))
    assert d.state == BehaviourState.PULLOVER and d.stop_reason == StopReason.DROP_OFF
    spot = d.stop_at_s_m
    assert spot is not None and spot - (10.0 + FRONT) >= C.transition_m - 1e-9
    assert d.pullover_spot is not None
    # At rest the shuttle's right side keeps the curb-gap target to the kerb (d = -1.75).
    assert d.pullover_spot.y_m - G.width_m / 2.0 == pytest.approx(-1.75 + C.curb_gap_target_m)
    rear = spot - FRONT
    d = fsm.step(_inp(1.0, rear, d_m=d.pullover_spot.y_m, v=0.0))
    assert d.state == BehaviourState.ONBOARDING
    walker = _tracks([(8, rear + 5.0, -2.8, 0.0, 0.0, ObjectClass.PEDESTRIAN)])
    t = 1.0
    for dt, door, person in ((0.5, True, True), (3.0, True, False), (9.5, True, False), (9.6, False, False)):
        d = fsm.step(_inp(t + dt, rear, door=door, person=person, tracks=walker))
    t += 9.6
    # Door closed, standing 9.6 s (> 8 s), but someone stands near the kerb ahead of the door.
    for k in range(50):
        d = fsm.step(_inp(t + 0.1 * k, rear, tracks=walker))
        assert d.state == BehaviourState.ONBOARDING and "pedestrian track 8" in d.reason
    t += 5.0
    # They leave: one second clear, then the merge.
    d = fsm.step(_inp(t, rear))
    assert d.state == BehaviourState.ONBOARDING
    d = fsm.step(_inp(t + D.clear_for_s, rear))
    assert d.state == BehaviourState.MERGING and fsm.mission.drop_offs_served == 1
    assert d.pullover_spot is not None, "the merge starts from the kerbside spot"


def test_the_wait_is_at_least_wait_s_from_the_halt_even_with_a_quick_door(straight_layers) -> None:
    slow = dataclasses.replace(C, drop_off=dataclasses.replace(D, wait_s=20.0))
    fsm = BehaviourStateMachine(
        layers=straight_layers, geometry=G, mission=MissionManager(("S1", "S2")), config=slow
    )
    fsm.mission.on_drop_off(DropOffRequestFrame(stamp=Stamp(0)))
    d = fsm.step(_inp(0.0, 10.0, v=5.0))
    rear = d.stop_at_s_m - FRONT
    fsm.step(_inp(1.0, rear))
    t = _door_cycle(fsm, 1.0, rear)
    d = fsm.step(_inp(t + 1.5, rear))
    assert d.state == BehaviourState.ONBOARDING and "standing" in d.reason
    d = fsm.step(_inp(21.0, rear))
    assert d.state == BehaviourState.MERGING


def test_drop_off_config_refuses_nonsense_in_one_line() -> None:
    with pytest.raises(ConfigError, match=r"DropOffConfig\.wait_s"):
        DropOffConfig(wait_s=-1.0)
    with pytest.raises(ConfigError, match=r"DropOffConfig\.max_curvature_1pm"):
        DropOffConfig(max_curvature_1pm=0.0)


def test_a_stop_served_anyway_must_be_left_its_own_pull_over(straight_layers) -> None:
    """From s 130 (front) S1's platform is 70 m ahead. Not wanted, the kerb 32 m on is used; wanted
    (riders wait there), its pull-over begins 45 m before it, so the rider gets off at S1 instead."""
    fsm = _fsm(straight_layers)
    fsm.mission.on_drop_off(DropOffRequestFrame(stamp=Stamp(0)))
    d = fsm.step(_inp(0.0, 130.0 - FRONT, v=5.0))
    assert d.state == BehaviourState.PULLOVER and d.stop_at_s_m == pytest.approx(162.0)
    fsm = _fsm(straight_layers)
    fsm.mission.requested.add("S1")
    fsm.mission.on_drop_off(DropOffRequestFrame(stamp=Stamp(0)))
    d = fsm.step(_inp(0.0, 130.0 - FRONT, v=5.0))
    assert d.state == BehaviourState.NORMAL_DRIVING and fsm.memory.drop_off.deferred_stop_id == "S1"


def test_the_drop_off_request_is_latched_until_served_and_checked_as_a_frame() -> None:
    from lastmile.core.errors import MessageError

    mission = MissionManager(stop_order=("S1",))
    mission.on_drop_off(DropOffRequestFrame(stamp=Stamp(2_000_000), seat=3))
    mission.on_drop_off(
        DropOffRequestFrame(stamp=Stamp(5_000_000), seat=3)
    )  # pressed again: the same request
    assert mission.drop_off_since_s == 2.0
    mission.drop_off_served()
    assert not mission.drop_off_pending and mission.drop_offs_served == 1
    with pytest.raises(MessageError, match="seat"):
        DropOffRequestFrame(stamp=Stamp(0), seat=-2).validate()


def test_a_stops_door_cycle_serves_a_request_only_if_the_door_was_open_after_it(straight_layers) -> None:
    def at_s1(press_while_closing: bool) -> MissionManager:
        fsm = _fsm(straight_layers)
        fsm.mission.requested.add("S1")
        d = fsm.step(_inp(0.0, 170.0, v=3.0))
        rear = d.stop_at_s_m - FRONT
        fsm.step(_inp(1.0, rear))  # arrived: ONBOARDING
        fsm.step(_inp(2.0, rear, door=True))
        if not press_while_closing:
            fsm.mission.on_drop_off(DropOffRequestFrame(stamp=Stamp(3_000_000)))
        fsm.step(_inp(3.0, rear, door=True))
        fsm.step(_inp(11.0, rear, door=True))  # dwell and doorway clear: the door starts closing
        if press_while_closing:
            fsm.mission.on_drop_off(DropOffRequestFrame(stamp=Stamp(11_500_000)))
        fsm.step(_inp(11.5, rear, door=True))
        fsm.step(_inp(12.0, rear))  # closed: MERGING
        assert fsm.state == BehaviourState.MERGING
        return fsm.mission

    assert at_s1(press_while_closing=False).drop_offs_served == 1
    late = at_s1(press_while_closing=True)
    assert late.drop_offs_served == 0 and late.drop_off_pending, "the rider is still on board"
