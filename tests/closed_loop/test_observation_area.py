"""Snow Lion's observation area at the campus's unprotected junction (the driveway out of Lot N, route s
1574-1590), closed loop with ``planner = "snow_lion_behaviour"``, radar tracking.

A car comes out of the lot (lanelet 1531, then a right turn into the shuttle's lane) as the shuttle
approaches: the shuttle stops at the line before the junction while the car crosses into its lane,
then follows it through.
"""

from __future__ import annotations

import dataclasses

import pytest

from lastmile.planning.planners import PlannerName
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import MapCar, Scenario
from tests.closed_loop.harness import RADAR, steps

pytestmark = pytest.mark.closed_loop
NO_RIDERS = PassengerConfig(arrivals_per_stop_per_min=0.0, initial_waiting={})
SNOW_LION = dataclasses.replace(
    RADAR, stack=dataclasses.replace(RADAR.stack, planner=PlannerName.SNOW_LION_BEHAVIOUR)
)
LINE_S_M = 1573.0
"""The stop line: 1 m before the junction's first route record."""
CROSSING_Y_M = 283.5
"""North of this the car is still coming across, not yet in the shuttle's lane (y 280-283.5)."""


def test_stops_at_the_line_for_a_car_coming_out_of_the_lot_then_follows_it() -> None:
    car = MapCar(spawn_t_s=4.0, speed_mps=3.0, from_lanelet=1531, distance_m=120.0)
    scenario = Scenario(
        name="lot_exit", minutes=0.6, passengers=NO_RIDERS, start_route_s_m=1535.0, map_cars=(car,)
    )
    slowed_at_line = False
    crossing_fronts = []
    stop_points = []
    last = None
    for step in steps(scenario, config=SNOW_LION):
        last = step
        w = step.sim.world
        front_s = step.sim.judge.route_s_m + 3.75  # type: ignore[attr-defined]
        if step.out.trajectory is not None and step.out.trajectory.stop_at_route_s_m is not None:
            stop_points.append(step.out.trajectory.stop_at_route_s_m)
        if w.ego.state.speed_mps < 0.2 and LINE_S_M - 3.0 < front_s <= LINE_S_M + 0.3:
            slowed_at_line = True
        car_y = [a.y_m for a in w.agents if a.active and a.cls.name == "CAR"]
        if car_y and car_y[0] > CROSSING_Y_M:
            crossing_fronts.append(front_s)
    assert last is not None
    assert stop_points and min(stop_points) == pytest.approx(LINE_S_M), "no lane stop was ordered"
    assert slowed_at_line, "the shuttle did not wait at the line"
    assert crossing_fronts and max(crossing_fronts) <= LINE_S_M + 0.3, "it entered while the car crossed"
    events = [e for e in last.sim.judge.events if e[1] in ("collision", "takeover", "rule_violation")]  # type: ignore[attr-defined]
    assert not events, events
    assert last.sim.judge.route_s_m > 1600.0, "it did not go on through the junction"  # type: ignore[attr-defined]
