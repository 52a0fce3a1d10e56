"""The referee's speed limit: on a route map, the limit the map states for the lanelet under the shuttle
(the route file's where it states none); the campus service keeps its fixed 20 km/h."""

from __future__ import annotations

import math

import pytest

from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation


def _speeding_events(map_limits: bool, speed_mps: float, unmapped_mps: float | None = None) -> list[str]:
    hdmap = load_campus_map()
    route = route_polyline(hdmap, campus_shuttle_loop(hdmap), closed=True)
    sim = Simulation(
        Scenario(name="speed", minutes=1.0),
        hdmap,
        route,
        VehicleGeometry(),
        10_000,
        map_speed_limits=map_limits,
        unmapped_speed_limit_mps=unmapped_mps,
    )
    # A 10 km/h lanelet of the campus map, the shuttle on its centre line heading along it.
    slow = next(
        ll
        for ll in hdmap.lanelets.values()
        if math.isclose(ll.speed_limit_mps, 10 / 3.6, abs_tol=1e-6)
        and hdmap.lanelet_at(*ll.centerline.point_at(ll.centerline.length_m / 2)[:2]) == ll.id
    )
    x, y, yaw = slow.centerline.point_at(slow.centerline.length_m / 2)
    s = sim.world.ego.state
    g = sim.world.geometry
    back = g.length_m / 2 - g.rear_overhang_m  # the state is the rear axle; put the centre on the line
    s.x_m, s.y_m, s.yaw_rad, s.speed_mps = x - back * math.cos(yaw), y - back * math.sin(yaw), yaw, speed_mps
    sim.world.agents = []
    assert hdmap.lanelet_at(*sim.world.ego_centre()) == slow.id
    for tick in range(150):
        sim.world.t_s = tick * 0.01
        sim.judge.step()
    return [str(d.get("detail")) for _, kind, d in sim.judge.events if d.get("rule") == "speed_limit"]


def test_on_a_route_map_the_referee_judges_the_mapped_limit() -> None:
    assert len(_speeding_events(map_limits=True, speed_mps=12 / 3.6)) == 1  # 12 km/h on a 10 km/h lane
    assert _speeding_events(map_limits=True, speed_mps=11 / 3.6) == []  # within the 0.5 m/s tolerance


@pytest.mark.parametrize("speed_kph", [12.0, 19.0])
def test_the_campus_referee_keeps_its_fixed_limit(speed_kph: float) -> None:
    assert _speeding_events(map_limits=False, speed_mps=speed_kph / 3.6) == []
