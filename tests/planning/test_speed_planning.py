"""The wired s-t + QP speed planner on a straight road: its inputs, event-driven replanning, the reference."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, StopReason, Trajectory
from lastmile.planning.speed_planning import SpeedInput, StQpSpeedPlanning, terminal_gap_m

ROUTE = Polyline(np.array([[0.0, 0.0], [400.0, 0.0]]))
HALF_W, LENGTH = 1.0, 4.6
FRONT = 23.75  # the front bumper's route s; the rear axle at 20


def _trajectory() -> Trajectory:
    x = np.arange(15.0, 90.0, 1.0)
    return Trajectory(
        stamp=Stamp(0),
        points=np.c_[x, np.zeros_like(x), np.zeros_like(x), np.zeros_like(x), x - 15.0],
        route_s0_m=15.0,
    )


def _obstacle(
    s_m: float, d_m: float = 0.0, v_s: float = 0.0, v_d: float = 0.0, cls: ObjectClass = ObjectClass.CAR,
    track_id: int = 1,
) -> RouteObstacle:  # fmt: skip
    size = (4.5, 1.8) if cls is ObjectClass.CAR else (0.5, 0.5)
    return RouteObstacle(
        track_id=track_id, cls=cls, x_m=s_m, y_m=d_m, s_m=s_m, ds_m=s_m - FRONT, d_m=d_m, v_s_mps=v_s,
        v_d_mps=v_d, length_m=size[0], width_m=size[1],
    )  # fmt: skip


def _input(t_s: float, obstacles: list[RouteObstacle], speed: float = 4.0, **kw: object) -> SpeedInput:
    travelled = speed * t_s
    base = {
        "now_s": t_s,
        "trajectory": _trajectory(),
        "front_s_m": FRONT + travelled,
        "path_s_m": 5.0 + travelled,
        "speed_mps": speed,
        "accel_mps2": 0.0,
        "cap_mps": 5.0,
        "stop_gap_m": None,
        "obstacles": obstacles,
    }
    base.update(kw)
    return SpeedInput(**base)  # type: ignore[arg-type]


def _planner() -> StQpSpeedPlanning:
    return StQpSpeedPlanning(ROUTE, HALF_W, LENGTH, 3.75)


def test_an_open_road_is_replanned_only_near_the_end_of_the_plan() -> None:
    sp = _planner()
    done = [sp.update(_input(0.1 * k, [])) for k in range(60)]
    assert done[0]
    # An 8 s plan is replaced once it has less than ``replan_remaining_s`` (3 s) left: at 5 s.
    assert [0.1 * k for k, d in enumerate(done) if d][:2] == pytest.approx([0.0, 5.1], abs=0.051)
    assert sp.replans == 2 and sp.cycles == 60


def test_a_road_user_in_the_path_is_replanned_every_cycle_and_followed() -> None:
    sp = _planner()
    lead = _obstacle(45.0, v_s=3.0)
    assert all(sp.update(_input(0.1 * k, [lead], speed=4.0)) for k in range(5))
    plan = sp.plan
    assert plan is not None and plan.solved
    # It slows to the lead's speed and keeps the gap and the headway behind its rear.
    gap = (45.0 - 2.25 + 3.0 * plan.t_s) - (FRONT + 0.4 * 4.0 + plan.s_m)
    assert np.all(gap >= sp.config.st.follow_gap_m - 0.05)
    assert plan.v_mps[-1] == pytest.approx(3.0, abs=0.4)
    assert np.all(plan.a_mps2 >= -sp.config.st.max_decel_mps2 - 1e-3)
    assert np.all(np.abs(plan.jerk_mps3) <= sp.config.st.max_jerk_mps3 + 1e-3)


def test_a_change_of_the_stop_point_or_the_cap_is_an_event() -> None:
    sp = _planner()
    sp.update(_input(0.0, []))
    assert not sp.update(_input(0.1, []))
    assert sp.update(_input(0.2, [], stop_gap_m=30.0))
    assert not sp.update(_input(0.3, [], stop_gap_m=30.0 - 0.4))  # the same point, 0.4 m nearer
    assert sp.update(_input(0.4, [], stop_gap_m=20.0))
    assert sp.update(_input(0.5, [], stop_gap_m=20.0 - 0.4, cap_mps=3.0))


def test_a_standing_obstacle_brings_the_plan_to_rest_and_gives_the_controller_its_gap() -> None:
    sp = _planner()
    box = _obstacle(40.0)
    sp.update(_input(0.0, [box]))
    v, gap = sp.reference(0.0, FRONT, None, 4.0)
    assert v == pytest.approx(4.0, abs=0.3)
    assert gap is not None
    # The plan rests short of ``follow_gap_m`` behind the box's rear (16.25 - 2.25 m ahead of the
    # front), never past it (the QP's approach ends within 2 m of the bound).
    follow = 40.0 - 2.25 - FRONT - sp.config.st.follow_gap_m
    assert follow - 2.0 <= gap <= follow
    assert sp.plan is not None and sp.plan.v_mps[-1] < sp.config.rest_speed_mps


def test_the_pedestrian_clearance_limit_binds_beside_a_pedestrian() -> None:
    sp = _planner()
    ped = _obstacle(40.0, d_m=-1.9, cls=ObjectClass.PEDESTRIAN)  # 0.65 m from the body's side
    stations = np.arange(0.0, 60.0, 1.0)
    limit, binds = sp._limits(_input(0.0, [ped]), stations)
    assert binds
    beside = (stations >= 40.0 - FRONT - 0.25) & (stations <= 40.0 - FRONT + LENGTH)
    # Clearance 0.65 m less the 0.5 m inflation: below delta_min, the walking-pace limit.
    assert np.all(limit[beside] <= sp.config.clearance.v_min_mps + 1e-9)
    assert np.all(limit[stations < 40.0 - FRONT - 1.0] > 4.0)
    far = _obstacle(40.0, d_m=-5.5, cls=ObjectClass.PEDESTRIAN)
    assert not sp._limits(_input(0.0, [far]), stations)[1]


def test_decisions_point_behind_a_moving_lead_is_not_the_plans_terminal_stop() -> None:
    decision = BehaviourDecision(
        stamp=Stamp(0), state=BehaviourState.NORMAL_DRIVING, speed_limit_mps=5.0, stop_at_s_m=50.0,
        pullover_spot=None, merge_from_s_m=None, door_open=False, risk_track_id=1, reason="",
        stop_reason=StopReason.OBSTACLE,
    )  # fmt: skip
    assert terminal_gap_m(decision, [_obstacle(60.0, v_s=3.0)], ROUTE, FRONT) is None
    assert terminal_gap_m(decision, [_obstacle(60.0)], ROUTE, FRONT) == pytest.approx(50.0 - FRONT)
    light = dataclasses.replace(decision, stop_reason=StopReason.TRAFFIC_LIGHT, risk_track_id=-1)
    assert terminal_gap_m(light, [_obstacle(60.0, v_s=3.0)], ROUTE, FRONT) == pytest.approx(50.0 - FRONT)
    # The controller gets decision's point behind the followed lead only when holding it is urgent.
    sp = _planner()
    sp.update(_input(0.0, [_obstacle(60.0, v_s=3.0)], following=True))
    assert sp.reference(0.0, FRONT, 20.0, 4.0)[1] is None  # 0.4 m/s^2 would do
    assert sp.reference(0.0, FRONT, 3.0, 4.0)[1] == pytest.approx(3.0)  # 2.7 m/s^2: urgent
    assert math.isfinite(sp.reference(0.0, FRONT, None, 4.0)[0])
