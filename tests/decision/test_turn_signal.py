"""The indicator rule: decision's lateral moves, passes, and the route's turns and lane changes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import (
    BehaviourDecision,
    BehaviourState,
    PassRequest,
    StopReason,
    TurnSignal,
)
from lastmile.decision.turn_signal import (
    UVC_SIGNAL_DISTANCE_M,
    ManoeuvreKind,
    TurnSignalConfig,
    TurnSignalRule,
)
from lastmile.hdmap.layers import INTERSECTION, SLayerDatabase
from lastmile.hdmap.model import HDMap, LaneletInfo
from lastmile.hdmap.service_route import load_route

BODY_M = 4.5


def _lanelet(lid: int, *, turn: str = "", left_bound: int = 0, right_bound: int = 0) -> LaneletInfo:
    line = Polyline(np.array([[0.0, 0.0], [1.0, 0.0]]))  # the rule reads ids, tags and bounds only
    return LaneletInfo(
        id=lid,
        centerline=line,
        left=line,
        right=line,
        speed_limit_mps=5.0,
        turn=turn,
        left_bound_id=left_bound,
        right_bound_id=right_bound,
    )


def _layers(
    lanelets: list[LaneletInfo],
    ids: np.ndarray,
    xy: np.ndarray | None = None,
    road_type: np.ndarray | None = None,
    closed: bool = False,
) -> SLayerDatabase:
    n = len(ids)
    line = Polyline(xy if xy is not None else np.array([[0.0, 0.0], [float(n), 0.0]]), closed=closed)
    return SLayerDatabase(
        hdmap=HDMap(name="t", lanelets={ll.id: ll for ll in lanelets}, successor_ids={}),
        centerline=line,
        step_m=1.0,
        s_m=np.arange(n, dtype=float),
        speed_limit_mps=np.full(n, 5.0),
        lane_left_d_m=np.full(n, 1.75),
        lane_right_d_m=np.full(n, -1.75),
        curb_right_d_m=np.full(n, np.nan),
        road_type=road_type if road_type is not None else np.zeros(n, dtype=np.int8),
        lanelet_id=ids.astype(np.int64),
    )


def _decision(
    state: BehaviourState = BehaviourState.NORMAL_DRIVING,
    stop_reason: StopReason = StopReason.NONE,
    pass_request: PassRequest | None = None,
) -> BehaviourDecision:
    return BehaviourDecision(
        stamp=Stamp(0),
        state=state,
        speed_limit_mps=5.0,
        stop_at_s_m=None,
        pullover_spot=SE2(0.0, 0.0, 0.0) if state is BehaviourState.PULLOVER else None,
        merge_from_s_m=None,
        door_open=False,
        risk_track_id=-1,
        reason="test",
        stop_reason=stop_reason,
        pass_request=pass_request,
    )


def _lane_change_rule(left: bool) -> TurnSignalRule:
    """200 m of road; the route moves to the lane beside it at s = 100."""
    right_lane = _lanelet(1, left_bound=100)
    left_lane = _lanelet(2, right_bound=100)
    first, second = (right_lane, left_lane) if left else (left_lane, right_lane)
    ids = np.where(np.arange(200) < 100, first.id, second.id)
    return TurnSignalRule(_layers([first, second], ids), BODY_M)


@pytest.mark.parametrize(("left", "expected"), [(True, TurnSignal.LEFT), (False, TurnSignal.RIGHT)])
def test_a_route_lane_change_is_signalled_from_100_ft_before_until_the_body_is_across(
    left: bool, expected: TurnSignal
) -> None:
    rule = _lane_change_rule(left)
    (m,) = rule.manoeuvres
    assert m.kind is ManoeuvreKind.LANE_CHANGE and m.start_s_m == 100.0
    d = _decision()
    assert rule.signal(d, 100.0 - UVC_SIGNAL_DISTANCE_M - 0.5) is TurnSignal.OFF
    assert rule.signal(d, 100.0 - UVC_SIGNAL_DISTANCE_M + 0.5) is expected
    assert rule.signal(d, 100.0 + BODY_M - 0.5) is expected
    assert rule.signal(d, 100.0 + BODY_M + 0.5) is TurnSignal.OFF


def test_consecutive_lanelets_that_are_not_side_by_side_are_no_lane_change() -> None:
    ids = np.where(np.arange(200) < 100, 1, 2)
    rule = TurnSignalRule(_layers([_lanelet(1, left_bound=7), _lanelet(2, right_bound=8)], ids), BODY_M)
    assert rule.manoeuvres == ()
    assert rule.signal(_decision(), 90.0) is TurnSignal.OFF


def test_a_tagged_turn_lanelet_is_signalled_through_the_turn() -> None:
    ids = np.select([np.arange(200) < 80, np.arange(200) < 95], [1, 2], 3)
    lanes = [_lanelet(1), _lanelet(2, turn="left"), _lanelet(3)]
    rule = TurnSignalRule(_layers(lanes, ids), BODY_M)
    (m,) = rule.manoeuvres
    assert (m.kind, m.signal, m.start_s_m, m.end_s_m) == (ManoeuvreKind.TURN, TurnSignal.LEFT, 80.0, 95.0)
    d = _decision()
    assert rule.signal(d, 80.0 - UVC_SIGNAL_DISTANCE_M - 0.5) is TurnSignal.OFF
    assert rule.signal(d, 60.0) is TurnSignal.LEFT
    assert rule.signal(d, 95.0 + BODY_M - 0.5) is TurnSignal.LEFT
    assert rule.signal(d, 95.0 + BODY_M + 0.5) is TurnSignal.OFF


def _corner_layers(junction: bool, straight_tag: bool = False) -> SLayerDatabase:
    """East 100 m, then south 100 m; lanelet 2 spans s 90-110 around the corner."""
    xy = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, -100.0]])
    ids = np.select([np.arange(200) < 90, np.arange(200) < 110], [1, 2], 3)
    road = np.zeros(200, dtype=np.int8)
    if junction:
        road[90:110] = INTERSECTION
    lanes = [_lanelet(1), _lanelet(2, turn="straight" if straight_tag else ""), _lanelet(3)]
    return _layers(lanes, ids, xy=xy, road_type=road)


def test_an_untagged_junction_lanelet_turns_by_its_heading_change_a_bend_off_a_junction_does_not() -> None:
    (m,) = TurnSignalRule(_corner_layers(junction=True), BODY_M).manoeuvres
    assert (m.signal, m.start_s_m, m.end_s_m) == (TurnSignal.RIGHT, 90.0, 110.0)
    assert TurnSignalRule(_corner_layers(junction=False), BODY_M).manoeuvres == ()
    # The map's own tag wins over the geometry.
    assert TurnSignalRule(_corner_layers(junction=True, straight_tag=True), BODY_M).manoeuvres == ()


def test_decision_states_set_the_signal_before_the_route() -> None:
    rule = _lane_change_rule(left=True)
    at = 90.0  # inside the lane change's window: left from the route
    assert rule.signal(_decision(BehaviourState.PULLOVER), at) is TurnSignal.RIGHT
    assert rule.signal(_decision(BehaviourState.MERGING, StopReason.REAR_TRAFFIC), at) is TurnSignal.LEFT
    assert rule.signal(_decision(BehaviourState.EMERGENCY_STOP), at) is TurnSignal.HAZARD
    mrm = _decision(BehaviourState.PULLOVER, StopReason.MINIMAL_RISK_MANOEUVRE)
    assert rule.signal(mrm, at) is TurnSignal.HAZARD
    assert rule.signal(_decision(), at, emergency_brake=True) is TurnSignal.HAZARD
    assert rule.signal(_decision(BehaviourState.ONBOARDING), at) is TurnSignal.OFF
    assert rule.signal(_decision(), at) is TurnSignal.LEFT


def test_a_pass_signals_left_moving_out_off_alongside_right_coming_back() -> None:
    rule = TurnSignalRule(_layers([_lanelet(1)], np.ones(200)), BODY_M)
    request = PassRequest(track_id=3, start_s_m=50.0, end_s_m=56.0, left_d_m=1.0, max_d_m=5.0, approved=True)
    d = _decision(pass_request=request)
    assert [rule.signal(d, s) for s in (40.0, 53.0, 60.0)] == [
        TurnSignal.LEFT,
        TurnSignal.OFF,
        TurnSignal.RIGHT,
    ]
    waiting = _decision(
        pass_request=PassRequest(track_id=3, start_s_m=50.0, end_s_m=56.0, left_d_m=1.0, max_d_m=5.0)
    )
    assert rule.signal(waiting, 40.0) is TurnSignal.OFF  # not approved: it waits in the lane


def test_a_closed_route_signals_a_manoeuvre_just_past_its_seam() -> None:
    ids = np.where(np.arange(200) < 10, 1, 2)  # the change at s = 10, approached from s = 190
    square = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0], [0.0, 0.0]])
    layers = _layers([_lanelet(1, left_bound=100), _lanelet(2, right_bound=100)], ids, xy=square, closed=True)
    rule = TurnSignalRule(layers, BODY_M)
    assert rule.route.closed
    assert rule.signal(_decision(), 195.0) is TurnSignal.LEFT
    assert rule.signal(_decision(), 170.0) is TurnSignal.OFF


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"advance_m": -1.0}, "advance_m"), ({"untagged_turn_min_rad": math.pi}, "untagged_turn_min_rad")],
)
def test_bad_configs_are_one_clear_line(kwargs: dict[str, float], field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        TurnSignalConfig(**kwargs)


def test_each_switch_on_is_counted_once() -> None:
    rule = _lane_change_rule(left=True)
    states = [BehaviourState.NORMAL_DRIVING, BehaviourState.PULLOVER, BehaviourState.PULLOVER]
    states += [BehaviourState.ONBOARDING, BehaviourState.MERGING, BehaviourState.MERGING]
    states += [BehaviourState.EMERGENCY_STOP, BehaviourState.PULLOVER]
    for state in states:
        rule.signal(_decision(state), 0.0)
    assert rule.counters() == {
        "turn_signal_left_on": 1,
        "turn_signal_right_on": 2,
        "turn_signal_hazard_on": 1,
    }


def _line_lanelet(lid: int, x0: float, x1: float, y: float) -> LaneletInfo:
    line = Polyline(np.array([[x0, y], [x1, y]]))
    return LaneletInfo(id=lid, centerline=line, left=line, right=line, speed_limit_mps=5.0)


@pytest.mark.parametrize(
    ("after_y", "expected"), [(3.5, TurnSignal.LEFT), (-3.5, TurnSignal.RIGHT), (0.5, None)]
)
def test_lanes_side_by_side_without_a_shared_bound_are_told_by_where_the_new_one_lies(
    after_y: float, expected: TurnSignal | None
) -> None:
    """Maps that draw each lane's bounds apart (the Lanelet2 example's roundabout): the new lane
    starting half a lane or more beside the old one is a lane over; nearer, no lane change."""
    ids = np.where(np.arange(150) < 100, 1, 2)
    lanes = [_line_lanelet(1, 0.0, 100.0, 0.0), _line_lanelet(2, 50.0, 150.0, after_y)]
    rule = TurnSignalRule(_layers(lanes, ids), BODY_M)
    assert [m.signal for m in rule.manoeuvres] == ([expected] if expected is not None else [])


EXAMPLE_MAP = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "maps" / "lanelet2_example"


@pytest.mark.skipif(
    not (EXAMPLE_MAP / "mapping_example.osm").is_file(),
    reason="../shared/data/maps/lanelet2_example is absent (real data lives beside the repository)",
)
def test_every_lane_change_of_the_lanelet2_example_route_gets_a_side(monkeypatch: pytest.MonkeyPatch) -> None:
    """The roundabout route changes lanes 7 times (as ``map check`` counts them: route lanelets that are
    not successors); each one is signalled, the tagged left turn too."""
    monkeypatch.chdir(Path(__file__).resolve().parents[2])
    service = load_route("examples/routes/lanelet2_example_roundabout.toml")
    rule = TurnSignalRule(service.layers(), BODY_M)
    ids = service.lanelet_ids
    changes = sum(
        1 for a, b in zip(ids, (*ids[1:], ids[0]), strict=True) if b not in service.hdmap.successors(a)
    )
    kinds = [m.kind for m in rule.manoeuvres]
    assert changes == 7 and kinds.count(ManoeuvreKind.LANE_CHANGE) == changes
    assert [m.signal for m in rule.manoeuvres if m.kind is ManoeuvreKind.TURN] == [TurnSignal.LEFT]
