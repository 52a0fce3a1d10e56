"""Cars whose lane-following prediction enters the shuttle's corridor: followed before they arrive.

Straight test road (route along y = 0, eastbound, centre of the shuttle's lane). The predicted paths
are written by hand here (tracking's predictor has its own tests); what is checked is what decision
does with them.
"""

import dataclasses

import numpy as np
import pytest

from lastmile.core.object_class import ObjectClass
from lastmile.core.predictions import PREDICTION_MODES, PredictedPaths
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourState
from tests.decision.test_behaviour_fsm import G, _fsm, _inp, _tracks

TIMES_S = np.arange(0.5, 6.01, 0.5)


def _paths(tid: int, xy: np.ndarray, mode: str = "lane_following") -> PredictedPaths:
    return PredictedPaths(
        stamp=Stamp(0),
        ids=np.array([tid]),
        times_s=TIMES_S,
        xy_m=xy[None],
        std_m=np.full((1, len(TIMES_S)), 0.5),
        mode=np.array([PREDICTION_MODES.index(mode)]),
    )


def _turning_in(x_m: float, y0_m: float, v_mps: float = 4.0) -> np.ndarray:
    """North up a side road at x_m from y0_m, then east along the shuttle's lane, at v_mps."""
    t_turn = -y0_m / v_mps
    return np.array(
        [(x_m, y0_m + v_mps * t) if t <= t_turn else (x_m + v_mps * (t - t_turn), 0.0) for t in TIMES_S]
    )


def test_a_car_turning_in_ahead_is_followed_from_where_it_enters(straight_layers):
    car = _tracks([(7, 110.0, -8.0, 0.0, 4.0, ObjectClass.CAR)])
    plain = _inp(0.0, 80.0, v=5.0, tracks=car)
    # Without the prediction the car, 8 m to the side, is not in the corridor: nothing to stop for.
    assert _fsm(straight_layers).step(plain).stop_at_s_m is None
    d = _fsm(straight_layers).step(
        dataclasses.replace(plain, predictions=_paths(7, _turning_in(110.0, -8.0)))
    )
    assert d.risk_track_id == 7 and "cut-in" in d.reason
    # Entry at the first predicted centre inside the corridor (s 110, at 1.5 s, still heading north):
    # a lead with no speed along the route yet, so the shuttle plans to stop half its length and the
    # 3 m gap short of it.
    assert d.stop_at_s_m == pytest.approx(110.0 - 2.25 - 3.0, abs=1e-6)
    assert d.state == BehaviourState.NORMAL_DRIVING


def test_a_prediction_alone_never_makes_an_emergency_stop(straight_layers):
    # Entering 3 m ahead of the front at 5.5 m/s would need far more than the emergency threshold if
    # the car were there; it is only predicted to be, so the shuttle brakes as hard as allowed, no harder.
    front_s = 110.0 - 3.0
    car = _tracks([(7, 110.0, -6.0, 0.0, 4.0, ObjectClass.CAR)])
    inp = _inp(0.0, front_s - G.front_from_rear_axle_m, v=5.5, tracks=car)
    d = _fsm(straight_layers).step(dataclasses.replace(inp, predictions=_paths(7, _turning_in(110.0, -6.0))))
    assert d.risk_track_id == 7 and d.state == BehaviourState.NORMAL_DRIVING


def test_a_car_that_arrives_after_the_shuttle_has_passed_is_not_waited_for(straight_layers):
    # The car reaches the corridor at 3.5 s; the shuttle's front, 4.75 m short of that point at
    # 5.5 m/s, gets there in 0.9 s: more than the 2 s margin before the car.
    front_s = 110.0 - 4.75
    car = _tracks([(7, 110.0, -16.0, 0.0, 4.0, ObjectClass.CAR)])
    inp = _inp(0.0, front_s - G.front_from_rear_axle_m, v=5.5, tracks=car)
    d = _fsm(straight_layers).step(dataclasses.replace(inp, predictions=_paths(7, _turning_in(110.0, -16.0))))
    assert d.stop_at_s_m is None


@pytest.mark.parametrize(
    ("row", "path", "mode"),
    [
        # Oncoming in the other lane (3.5 m left): its lane never enters the corridor.
        (
            (7, 140.0, 3.5, -8.0, 0.0),
            np.c_[140.0 - 8.0 * TIMES_S, np.full(len(TIMES_S), 3.5)],
            "lane_following",
        ),
        # Beside the shuttle in the bay lane, merging ahead: at or behind the front is merging's concern.
        (
            (7, 83.0, -3.25, 10.0, 0.0),
            np.c_[83.0 + 10.0 * TIMES_S, np.minimum(-3.25 + 2.0 * TIMES_S, 0.0)],
            "lane_following",
        ),
        # Not a lane-following path (constant velocity): the in-path test's business, not this rule's.
        ((7, 110.0, -8.0, 0.0, 4.0), _turning_in(110.0, -8.0), "constant_velocity"),
        # Stopping at a stop line 4 m short of the lane: never enters.
        (
            (7, 110.0, -12.0, 0.0, 4.0),
            np.c_[np.full(len(TIMES_S), 110.0), np.minimum(-12.0 + 4.0 * TIMES_S, -6.0)],
            "lane_following",
        ),
    ],
    ids=["oncoming", "beside-or-behind", "constant-velocity", "stops-at-its-line"],
)
def test_paths_that_do_not_cut_in_ahead_are_ignored(straight_layers, row, path, mode):
    tid, x, y, vx, vy = row
    car = _tracks([(tid, x, y, vx, vy, ObjectClass.CAR)])
    inp = _inp(0.0, 80.0, v=5.0, tracks=car)
    d = _fsm(straight_layers).step(dataclasses.replace(inp, predictions=_paths(tid, path, mode)))
    assert d.stop_at_s_m is None and "cut-in" not in d.reason


def test_a_car_already_driving_along_when_it_enters_is_followed_at_its_speed(straight_layers):
    # Changing into the lane from the left at a shallow angle (12 m ahead, 6 m/s east, 1 m/s south):
    # along the route it already moves at 6 m/s where it enters, so the stop point is v^2 / 6 further.
    path = np.c_[100.0 + 6.0 * TIMES_S, np.maximum(3.5 - 1.0 * TIMES_S, 0.0)]
    car = _tracks([(7, 100.0, 3.5, 6.0, -1.0, ObjectClass.CAR)])
    inp = _inp(0.0, 80.0, v=5.0, tracks=car)
    d = _fsm(straight_layers).step(dataclasses.replace(inp, predictions=_paths(7, path)))
    entry_x = 100.0 + 6.0 * 1.5  # y = 2.0 at 1.5 s: inside 1.0 + 0.5 + 0.9 = 2.4 m
    assert d.risk_track_id == 7
    assert d.stop_at_s_m == pytest.approx(entry_x - 2.25 + 6.0**2 / 6.0 - 3.0, abs=1e-6)


def _crossing(x_m: float, y0_m: float, v_mps: float = 6.0) -> np.ndarray:
    """Straight north across the shuttle's lane at x_m (a car turning left across it)."""
    return np.c_[np.full(len(TIMES_S), x_m), y0_m + v_mps * TIMES_S]


def test_a_car_crossing_the_lane_is_waited_for_only_if_still_crossing_when_the_shuttle_arrives(
    straight_layers,
):
    # From 4 m south of the lane at 6 m/s: in the corridor (|y| < 2.4 m) from 0.5 s to 1.0 s.
    car = _tracks([(7, 130.0, -4.0, 0.0, 6.0, ObjectClass.CAR)])
    paths = _paths(7, _crossing(130.0, -4.0))
    # Front 46 m short at 5 m/s: it arrives at 9.2 s, long after the car has crossed (1.0 s + 2 s).
    far = _inp(0.0, 130.0 - 46.0 - G.front_from_rear_axle_m, v=5.0, tracks=car)
    assert _fsm(straight_layers).step(dataclasses.replace(far, predictions=paths)).stop_at_s_m is None
    # Front 12 m short: it arrives at 2.4 s, within 2 s of the car leaving: wait for it to cross.
    near = _inp(0.0, 130.0 - 12.0 - G.front_from_rear_axle_m, v=5.0, tracks=car)
    d = _fsm(straight_layers).step(dataclasses.replace(near, predictions=paths))
    assert d.risk_track_id == 7 and d.stop_at_s_m == pytest.approx(130.0 - 2.25 - 3.0, abs=1e-6)
