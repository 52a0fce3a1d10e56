"""The offset-pass planner on a straight road: the quintic lattice, its checks, and its fall-backs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, PassRequest
from lastmile.planning.pass_path import QUINTIC_PEAK, OffsetPassPlanner, pass_offsets_m

HALF_W, BEHIND, AHEAD = 1.0, 0.85, 3.75
CAR_S = 100.0
REQUEST = PassRequest(
    track_id=1,
    start_s_m=CAR_S - 2.25,
    end_s_m=CAR_S + 2.25,
    left_d_m=0.9,
    max_d_m=5.25,
    lookout_d_m=0.3,
    wait_s_m=CAR_S - 2.25 - 20.0,
    approved=True,
)


def _planner(drivable: object = None) -> OffsetPassPlanner:
    route = Polyline(np.array([[0.0, 0.0], [300.0, 0.0]]))
    return OffsetPassPlanner(
        route,
        HALF_W,
        body_behind_m=BEHIND,
        body_ahead_m=AHEAD,
        drivable=drivable,
        max_curvature_1pm=0.21,  # type: ignore[arg-type]
    )


def _car(track_id: int = 1, s_m: float = CAR_S, d_m: float = 0.0, v_s_mps: float = 0.0) -> RouteObstacle:
    return RouteObstacle(
        track_id=track_id,
        cls=ObjectClass.CAR,
        x_m=s_m,
        y_m=d_m,
        s_m=s_m,
        ds_m=s_m - 60.0,
        d_m=d_m,
        v_s_mps=v_s_mps,
        v_d_mps=0.0,
        length_m=4.5,
        width_m=1.8,
    )


def _decision(request: PassRequest | None) -> BehaviourDecision:
    return BehaviourDecision(
        stamp=Stamp(0),
        state=BehaviourState.NORMAL_DRIVING,
        speed_limit_mps=4.0,
        stop_at_s_m=None,
        pullover_spot=None,
        merge_from_s_m=None,
        door_open=False,
        risk_track_id=-1,
        reason="",
        pass_request=request,
    )


S = np.arange(55.0, 160.0, 0.5)
EGO_S = 60.0  # the rear axle; the front 20 m behind the car's rear is at 73.75 m


def test_the_chosen_pass_clears_the_car_by_its_margin_and_comes_back_to_the_lane() -> None:
    planner = _planner()
    d = planner.offsets_m(S, _decision(REQUEST), [_car()], 0.3)
    beside = (S >= CAR_S - 2.25 - AHEAD) & (S <= CAR_S + 2.25 + BEHIND)
    assert np.all(d[beside] - HALF_W >= 0.9 + 1.0 - 1e-6)  # the body's right side 1 m off the car
    assert d.max() + HALF_W <= 5.25 - 0.3 + 1e-6  # the left side inside the far lane's edge
    assert d[0] == pytest.approx(0.0) and d[-1] == pytest.approx(0.0, abs=1e-9)  # in the lane either side
    assert planner.chosen is not None
    chosen = planner.chosen[1]
    # The move's peak curvature within what the steering follows (0.8 of 0.21 /m).
    assert QUINTIC_PEAK * (chosen.offset_m - 0.3) / chosen.length_m**2 <= 0.8 * 0.21 + 1e-9
    assert chosen.min_clearance_m >= 1.0 - 0.05
    # Several candidates were scored; the least offset that clears won (more offset costs more).
    assert len(planner.last_candidates) > 1
    assert chosen.offset_m == pytest.approx(0.9 + 1.0 + HALF_W)


def test_no_room_on_the_road_or_an_oncoming_car_on_the_way_leaves_the_lane_path() -> None:
    narrow = _planner(drivable=lambda xy: np.abs(np.asarray(xy)[:, 1]) <= 3.0)  # a 6 m road
    d = narrow.offsets_m(S, _decision(REQUEST), [_car()], 0.3)
    assert d.max() <= 0.3 + 1e-9 and narrow.chosen is None  # the look-out offset only: it waits
    planner = _planner()
    oncoming = _car(track_id=2, s_m=150.0, d_m=3.5, v_s_mps=-6.0)
    d = planner.offsets_m(S, _decision(REQUEST), [_car(), oncoming], 0.3)
    assert d.max() <= 0.3 + 1e-9 and planner.chosen is None
    assert all(not np.isfinite(k.cost) for k in planner.last_candidates)


def test_waiting_it_holds_the_look_out_offset_in_the_lane_and_a_begun_pass_keeps_its_move() -> None:
    planner = _planner()
    waiting = dataclasses.replace(REQUEST, approved=False)
    d = planner.offsets_m(S, _decision(waiting), [_car()], 0.0)
    at_wait = np.interp(REQUEST.wait_s_m - AHEAD, S, d)
    assert at_wait == pytest.approx(0.3) and d.max() == pytest.approx(0.3)
    planner.offsets_m(S, _decision(REQUEST), [_car()], 0.3)
    assert planner.chosen is not None
    first = planner.chosen[1]
    # Committed, and the car's left edge now seen 0.3 m further out: the same move, moved out.
    committed = dataclasses.replace(REQUEST, committed=True, left_d_m=1.2)
    planner.offsets_m(S + 10.0, _decision(committed), [_car()], 1.5)
    kept = planner.chosen[1]
    assert kept.length_m == first.length_m and kept.offset_m == pytest.approx(first.offset_m + 0.3)


def test_the_offsets_are_quintic_moves_between_the_look_out_and_the_held_offset() -> None:
    s = np.linspace(0.0, 60.0, 601)
    d = pass_offsets_m(s, out_by_m=20.0, back_from_m=35.0, offset_m=3.0, length_m=10.0, from_d_m=0.5)
    assert d[s <= 10.0] == pytest.approx(0.5) and d[(s >= 20.0) & (s <= 35.0)] == pytest.approx(3.0)
    assert d[s >= 45.0] == pytest.approx(0.0)
    slope = np.gradient(d, s)
    assert abs(slope[100]) < 1e-3 and abs(slope[200]) < 1e-2  # level where each move begins and ends
