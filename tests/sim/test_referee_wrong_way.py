"""The referee's wrong-way rule: the opposite lane is legal only to pass a standing obstruction across a
broken line."""

from __future__ import annotations

import math

import pytest

from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.service_route import campus_service
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import Scenario, StaticObstacle
from lastmile.sim.simulation import Simulation
from lastmile.sim.vehicle_model import VehicleState

NO_RIDERS = PassengerConfig(arrivals_per_stop_per_min=0.0, initial_waiting={})


def _violations_with_the_shuttle_at(
    route_s_m: float, d_m: float, obstacles: tuple[StaticObstacle, ...]
) -> list:
    service = campus_service()
    scenario = Scenario(
        name="wrong_way",
        minutes=0.1,
        passengers=NO_RIDERS,
        start_route_s_m=route_s_m,
        static_obstacles=obstacles,
    )
    sim = Simulation(scenario, service.hdmap, service.polyline, VehicleGeometry(), 10_000)
    x, y, yaw = service.polyline.point_at(route_s_m)
    sim.world.ego.state = VehicleState(x_m=x - d_m * math.sin(yaw), y_m=y + d_m * math.cos(yaw), yaw_rad=yaw)
    sim.judge.step()
    sim.judge.step()  # one event per episode, not per tick
    return [e for e in sim.judge.events if e[1].value == "rule_violation"]


def test_driving_in_the_opposite_lane_with_nothing_to_pass_is_a_violation() -> None:
    (event,) = _violations_with_the_shuttle_at(420.0, 3.3, ())
    assert event[2] == {"rule": "wrong_way", "detail": "no stationary obstruction to pass"}


def test_passing_a_parked_car_across_the_broken_line_is_legal() -> None:
    parked = StaticObstacle(route_s_m=425.0, kind="car", length_m=4.5, width_m=1.8)
    assert _violations_with_the_shuttle_at(420.0, 3.3, (parked,)) == []


@pytest.mark.parametrize("d_m", [0.0, 0.6])
def test_the_shuttle_in_its_own_lane_is_not_judged(d_m: float) -> None:
    assert _violations_with_the_shuttle_at(420.0, d_m, ()) == []


def test_crossing_the_solid_line_is_a_violation_even_to_pass() -> None:
    parked = StaticObstacle(route_s_m=255.0, kind="car", length_m=4.5, width_m=1.8)
    (event,) = _violations_with_the_shuttle_at(250.0, 3.3, (parked,))
    assert event[2] == {"rule": "wrong_way", "detail": "crossed a line_thin:solid line"}
