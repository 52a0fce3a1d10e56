"""The simulated safety driver's time to collision: other road users move on at their velocity, so an
oncoming car in its own lane is no conflict for a shuttle swinging out of a bay, while a pedestrian
stepping into the shuttle's path is one before they are in it."""

from __future__ import annotations

import math

import pytest

from lastmile.core.object_class import ObjectClass
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.sim.agents import Agent
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation


@pytest.fixture(scope="module")
def sim() -> Simulation:
    hdmap = load_campus_map()
    route = route_polyline(hdmap, campus_shuttle_loop(hdmap), closed=True)
    return Simulation(Scenario(name="ttc", minutes=1.0), hdmap, route, VehicleGeometry(), 10_000)


def _place(sim: Simulation, yaw_rad: float, speed_mps: float, agents: list[Agent], y_m: float = 0.0) -> None:
    s = sim.world.ego.state
    s.x_m, s.y_m, s.yaw_rad, s.speed_mps, s.yaw_rate_radps = 0.0, y_m, yaw_rad, speed_mps, 0.0
    sim.world.agents = agents


def _agent(
    aid: int, cls: ObjectClass, x: float, y: float, yaw: float, v: float, size: tuple[float, float]
) -> Agent:
    return Agent(
        id=aid,
        cls=cls,
        x_m=x,
        y_m=y,
        yaw_rad=yaw,
        speed_mps=v,
        length_m=size[0],
        width_m=size[1],
        rcs_dbsm=0.0,
    )


def test_an_oncoming_car_in_its_own_lane_is_no_conflict_for_a_shuttle_angled_out_of_a_bay(sim) -> None:
    # Our lane runs along +x at y = 0; the oncoming lane at y = +3.5. The shuttle's front has reached
    # its lane's centre pointing 0.26 rad to the left (merging), so the straight line ahead meets the
    # car 10 m on; by the time the two fronts meet (0.9 s) the car has moved on, 0.9 m clear.
    g = sim.world.geometry
    car = _agent(2, ObjectClass.CAR, 14.0, 3.5, math.pi, 6.0, (4.5, 1.8))
    _place(sim, 0.26, 3.0, [car], y_m=-g.front_from_rear_axle_m * math.sin(0.26))
    ttc, _ = sim.judge.time_to_collision()
    assert ttc == math.inf
    # The same car coming down our lane is a conflict.
    car_in_lane = _agent(2, ObjectClass.CAR, 14.0, 0.5, math.pi, 6.0, (4.5, 1.8))
    _place(sim, 0.26, 3.0, [car_in_lane], y_m=-g.front_from_rear_axle_m * math.sin(0.26))
    assert sim.judge.time_to_collision()[0] < 1.5


def test_a_car_standing_in_the_lane_ahead_gives_gap_over_speed(sim) -> None:
    g = sim.world.geometry
    car = _agent(3, ObjectClass.CAR, g.front_from_rear_axle_m + 10.0 + 2.25, 0.0, 0.0, 0.0, (4.5, 1.8))
    _place(sim, 0.0, 5.0, [car])
    ttc, who = sim.judge.time_to_collision()
    assert who == 3 and ttc == pytest.approx(10.0 / 5.0)


def test_a_pedestrian_stepping_into_the_path_is_a_conflict_before_they_are_in_it(sim) -> None:
    g = sim.world.geometry
    # 8 m ahead of the front, 2.5 m to the right (outside the 1.5 m corridor), walking in at 1.4 m/s.
    ped = _agent(
        4, ObjectClass.PEDESTRIAN, g.front_from_rear_axle_m + 8.0, -2.5, math.pi / 2, 1.4, (0.5, 0.5)
    )
    _place(sim, 0.0, 5.0, [ped])
    ttc, who = sim.judge.time_to_collision()
    assert who == 4 and ttc == pytest.approx((8.0 - 0.25) / 5.0)
    # Walking away from the path instead: no conflict.
    ped_away = _agent(
        5, ObjectClass.PEDESTRIAN, g.front_from_rear_axle_m + 8.0, -2.5, -math.pi / 2, 1.4, (0.5, 0.5)
    )
    _place(sim, 0.0, 5.0, [ped_away])
    assert sim.judge.time_to_collision()[0] == math.inf
