"""The example town: a Lanelet2 map with the junction kinds real shuttle routes meet, regenerated bit
for bit, read with every rule it states, and driven by the simulator's traffic rules per junction."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.traffic_light_messages import LightState
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.service_route import load_route
from lastmile.hdmap.town import write_town_map
from lastmile.sim.traffic_signals import ALL_RED_S, SignalConfig, SignalController, signal_phases
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState
from lastmile.sim.weather import Weather
from lastmile.sim.world import World

ROOT = Path(__file__).resolve().parents[2]
TOWN_OSM = ROOT / "examples" / "maps" / "town" / "town.osm"
ROUTE = ROOT / "examples" / "routes" / "town_block_loop.toml"


def test_committed_town_osm_is_what_the_generator_writes(tmp_path: Path) -> None:
    fresh = write_town_map(tmp_path / "town.osm")
    assert fresh.read_bytes() == TOWN_OSM.read_bytes(), (
        "run `python -m lastmile.hdmap.town examples/maps/town/town.osm`"
    )


def test_every_rule_the_town_states_is_read_and_the_loop_meets_each_kind_of_junction() -> None:
    service = load_route(ROUTE)
    hdmap = service.hdmap
    assert len(hdmap.all_way_stops) == 2
    by_stop = {
        aws.id: [sl for sl in hdmap.stop_lines if sl.all_way_stop_id == aws.id] for aws in hdmap.all_way_stops
    }
    # Main St / West Ave: four approaches whose lanelets do not reference the rule; North St / West Ave: a
    # T whose stem (North St, one way) only leaves it, so two approaches.
    assert sorted(len(lines) for lines in by_stop.values()) == [2, 4]
    assert len(hdmap.signals) == 4
    give_way = [sl for sl in hdmap.stop_lines if sl.all_way_stop_id is None and sl.signal_id is None]
    assert len(give_way) == 1
    layers = service.layers(step_m=1.0)
    on_route = layers.stop_lines
    assert sum(rl.all_way_stop_id is not None for rl in on_route) == 2
    assert sum(rl.stop_line.signal_id is not None for rl in on_route) == 1
    assert any(rl.stop_line.id == give_way[0].id for rl in on_route)
    assert len(layers.crosswalks) == 2
    # Turning lanelets carry no limit; the route file's 20 km/h applies there, the streets' 30 km/h elsewhere.
    limits = {round(layers.speed_limit_at(float(s)) * 3.6) for s in np.arange(0.0, layers.length_m, 2.0)}
    assert limits == {20, 30}


def test_crossing_approaches_of_the_signalised_junction_never_show_green_together() -> None:
    hdmap = load_route(ROUTE).hdmap
    cross = signal_phases(hdmap)
    assert len(cross) == 2  # the two approaches along one street; the other street's two run the main phase
    headings = {}
    for sig in hdmap.signals:
        centre = hdmap.lanelets[sig.lanelet_id].centerline
        headings[sig.id] = centre.heading_at(centre.length_m)
    main = [s for s in headings if s not in cross]
    for a in main:
        for b in cross:
            assert abs(math.cos(headings[a] - headings[b])) < 0.1  # perpendicular approaches
    config = SignalConfig()
    controller = SignalController(config, tuple(headings), cross)
    both, last_change, gaps = 0, None, []
    for t in np.arange(0.0, 3 * config.cycle_s, 0.05):
        m = controller.state(main[0], float(t))
        c = controller.state(next(iter(cross)), float(t))
        if m is not LightState.RED and c is not LightState.RED:
            both += 1
        all_red = m is LightState.RED and c is LightState.RED
        if all_red and last_change is None:
            last_change = float(t)
        if not all_red and last_change is not None:
            gaps.append(float(t) - last_change)
            last_change = None
    assert both == 0
    assert gaps and min(gaps) >= ALL_RED_S - 0.06  # the red clearance at every change of right of way
    assert any(
        controller.state(next(iter(cross)), float(t)) is LightState.GREEN for t in np.arange(0, 60, 0.5)
    )


def test_a_plan_with_no_room_for_the_cross_phase_is_one_clear_error() -> None:
    with pytest.raises(ConfigError, match=r"traffic_signals\.red_s"):
        SignalController(SignalConfig(red_s=5.0), (1, 2), frozenset({2}))


def test_each_all_way_stop_keeps_its_own_arrival_order() -> None:
    """A car waiting at one all-way stop is owed nothing at the other, and occupies only its own box."""
    hdmap = load_route(ROUTE).hdmap
    ego = KinematicBicycle(
        VehicleGeometry(), ActuatorDynamics(), VehicleState(x_m=100.0, y_m=60.0, yaw_rad=0.0)
    )
    world = World(hdmap, ego, [], Weather.CLEAR, np.random.default_rng(0))
    first, second = hdmap.all_way_stops
    line_a = next(sl.id for sl in hdmap.stop_lines if sl.all_way_stop_id == first.id)
    line_b = next(sl.id for sl in hdmap.stop_lines if sl.all_way_stop_id == second.id)
    assert world.arbiter(line_a) is not world.arbiter(line_b)
    world.arbiter(line_a).arrive(7, line_a, 0.0)
    assert world.arbiter(line_b).earlier_than(0) == []
    assert world.arbiter(line_a).earlier_than(0) == [7]
    assert world.anyone_waiting_at_all_way_stops()
