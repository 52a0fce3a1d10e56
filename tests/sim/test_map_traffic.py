"""Cars on the map's own lanelet graph (``map_cars``): on the campus map and on a real Lanelet2 map they
drive successor lanelets only, keep right on two-way lanelets, stop at all-way stops, wait for room to
appear, stream, and repeat bit for bit with the seed."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.hdmap.service_route import load_route
from lastmile.runner.loop import parked_ticks
from lastmile.sim.agents import PathCar
from lastmile.sim.map_traffic import MapTraffic, keep_right, random_walk
from lastmile.sim.scenario import MapCar, Scenario
from lastmile.sim.simulation import Simulation

TICK_US = 10_000
ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_MAP = ROOT.parent / "shared" / "data" / "maps" / "lanelet2_example" / "mapping_example.osm"


def _campus_sim(*cars: MapCar, seed: int = 0) -> Simulation:
    hdmap = load_campus_map()
    route = route_polyline(hdmap, campus_shuttle_loop(hdmap), closed=True)
    scenario = Scenario(name="map_traffic", minutes=1.0, seed=seed, map_cars=cars)
    return Simulation(scenario, hdmap, route, VehicleGeometry(), TICK_US)


def _map_cars(sim: Simulation) -> list[PathCar]:
    return [a for a in sim.world.agents if isinstance(a, PathCar)]


def test_a_walk_follows_successor_lanelets_and_repeats_with_its_seed() -> None:
    hdmap = load_campus_map()
    start = next(iter(sorted(hdmap.lanelets)))
    walks = [random_walk(hdmap, start, 500.0, np.random.default_rng(s)) for s in (1, 1, 2)]
    assert walks[0] == walks[1]
    for walk in walks:
        assert all(b in hdmap.successor_ids[a] for a, b in itertools.pairwise(walk))


def test_cars_stream_on_the_graph_stop_at_the_all_way_stop_and_repeat_bit_for_bit() -> None:
    hdmap = load_campus_map()
    # Cars start on the lanelets that end at the campus's all-way stop, each then walking on at random.
    before_stop = sorted({sl.lanelet_id for sl in hdmap.stop_lines if sl.all_way_stop_id is not None})
    specs = tuple(
        MapCar(spawn_t_s=0.0, every_s=5.0, distance_m=200.0, speed_mps=7.0, from_lanelet=lid)
        for lid in before_stop
    )
    runs = []
    for _ in range(2):
        sim = _campus_sim(*specs, seed=3)
        slowest_near_line: dict[int, float] = {}
        passed: set[int] = set()
        for _tick in parked_ticks(sim, range(3000)):  # 30 s
            for car in _map_cars(sim):
                for line in car.stop_lines:
                    to_line = line.s_m - car.s_m - car.length_m / 2.0
                    if -1.0 <= to_line <= 3.0:
                        slowest = slowest_near_line.get(car.id, math.inf)
                        slowest_near_line[car.id] = min(slowest, car.speed_mps)
                    elif to_line < -1.0 and car.id in slowest_near_line:
                        passed.add(car.id)
        assert not [e for e in sim.judge.events if e[1] == "collision"]
        cars = _map_cars(sim)
        assert len(cars) >= 2 * len(specs)  # streams: one every 5 s each, unless one waited for room
        runs.append([(c.id, c.x_m, c.y_m, c.speed_mps) for c in cars])
        # Every car that went through an all-way-stop line stood at it first (and some did go through).
        assert passed and all(slowest_near_line[car_id] < 0.2 for car_id in passed)
    assert runs[0] == runs[1]


def test_a_car_waits_for_room_rather_than_appearing_on_another_road_user() -> None:
    sim = _campus_sim()
    ego = sim.world.ego_centre()
    hdmap = sim.world.hdmap
    start = hdmap.lanelet_at(*ego)
    assert start is not None
    traffic = MapTraffic((MapCar(spawn_t_s=0.0, from_lanelet=start),), hdmap, seed=0)
    sim.world.t_s = 0.0
    car = traffic._build(MapCar(from_lanelet=start), 0, 0, 99)
    if math.hypot(car.x_m - ego[0], car.y_m - ego[1]) < 12.0:
        assert traffic.spawn_due(sim.world, 99) == []  # the shuttle stands there: not now
        sim.world.t_s = 1.5
        assert traffic.spawn_due(sim.world, 99) == []  # still there a second later
    else:
        pytest.skip("the shuttle's start lanelet begins farther than the clearance from the shuttle")


def test_an_unknown_start_lanelet_is_one_clear_error() -> None:
    with pytest.raises(ConfigError, match=r"map_cars\.from_lanelet: expected a lanelet of map"):
        _campus_sim(MapCar(from_lanelet=987654321))


@pytest.mark.skipif(
    not EXAMPLE_MAP.exists(),
    reason="../shared/data/maps/lanelet2_example is absent (real data lives beside the repository)",
)
def test_on_a_real_map_two_way_lanelets_are_driven_on_their_right_half(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(ROOT)
    hdmap = load_route("examples/routes/lanelet2_example_roundabout.toml").hdmap
    two_way = sorted(lid for lid in hdmap.lanelets if lid > 0 and -lid in hdmap.lanelets)
    assert two_way, "the Lanelet2 example has two-way lanelets"
    lid = two_way[0]
    centre = hdmap.lanelets[lid].centerline
    path = keep_right(route_polyline(hdmap, (lid,)), hdmap, (lid,))
    x, y, _ = path.point_at(path.length_m / 2.0)
    d = centre.project(x, y).d_m
    assert d < -0.3  # right of the shared centre line, by a quarter of the lanelet's width
    x, y, _ = centre.point_at(centre.length_m / 2.0)
    info = hdmap.lanelets[lid]
    width = abs(info.left.project(x, y).d_m) + abs(info.right.project(x, y).d_m)
    assert d == pytest.approx(-width / 4.0, abs=0.1)
