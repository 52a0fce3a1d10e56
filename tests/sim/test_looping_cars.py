"""Cars on the ring road keep behaving after their loop's seam: they follow the shuttle across s = 0
of their closed path and stop at the all-way stop on every lap."""

from __future__ import annotations

import math

from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.runner.loop import parked_ticks
from lastmile.sim.agents import PathCar
from lastmile.sim.scenario import RingCar, Scenario
from lastmile.sim.simulation import Simulation

TICK_US = 10_000


def _sim(ring_car: RingCar) -> tuple[Simulation, PathCar]:
    hdmap = load_campus_map()
    route = route_polyline(hdmap, campus_shuttle_loop(hdmap), closed=True)
    scenario = Scenario(name="loop", minutes=1.0, ring_cars=(ring_car,))
    sim = Simulation(scenario, hdmap, route, VehicleGeometry(), TICK_US)
    car = next(a for a in sim.world.agents if isinstance(a, PathCar))
    return sim, car


def test_a_car_behind_the_standing_shuttle_across_the_loop_seam_stops_behind_it() -> None:
    # The shuttle stands at route s = 0; the car comes from 40 m behind, near the end of its loop.
    sim, car = _sim(RingCar(direction="ccw", start_s_m=0.0, speed_mps=7.0))
    car.s_m = car.path.length_m - 40.0
    for _ in parked_ticks(sim, range(1500)):
        pass
    assert not [e for e in sim.judge.events if e[1] == "collision"]
    ex, ey = sim.world.ego_centre()
    gap_m = math.hypot(car.x_m - ex, car.y_m - ey) - (car.length_m + sim.world.geometry.length_m) / 2.0
    assert car.speed_mps < 0.1 and 1.0 < gap_m < 6.0


def test_a_lapping_car_stops_at_the_all_way_stop_again_on_its_next_lap() -> None:
    sim, car = _sim(RingCar(direction="cw", start_s_m=0.0, speed_mps=8.0))
    assert car.stop_lines, "the oncoming lane of the campus ring crosses the all-way stop"
    line = car.stop_lines[0]
    length_m = car.path.length_m
    car.s_m = line.s_m + 5.0  # just past the line: it has gone through it on this lap
    slowest_at_line_mps = math.inf
    for _ in parked_ticks(sim, range(60_000)):
        if car.s_m >= line.s_m + length_m + 10.0:
            break
        to_line_m = line.s_m + length_m - car.s_m - car.length_m / 2.0
        if -1.0 <= to_line_m <= 3.0:
            slowest_at_line_mps = min(slowest_at_line_mps, car.speed_mps)
    assert car.s_m >= line.s_m + length_m + 10.0, "the car went round and through the stop"
    assert slowest_at_line_mps < 0.2
