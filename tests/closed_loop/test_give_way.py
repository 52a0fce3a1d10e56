"""Give-way lines and gap acceptance in the loop, radar tracking (issue #20).

The example town's North Street yields to East Avenue at a give-way line (x = 190, eastbound; the
route turns right into East Ave's southbound lane). A car is sent down East Ave from the map's edge
(lanelet 211, y = 190) at 8 m/s; the right turn's conflict zone with its lane begins at y = 117.4 and
ends at y = 110. The shuttle starts on North St from rest, route s 240 (front 15 m before the line) or
220 (35 m).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import lastmile.runner.closed_loop as closed_loop
from lastmile.core.vehicle_messages import StopReason
from lastmile.hdmap.service_route import ServiceRoute, load_route
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import MapCar, MapSpec, Scenario
from tests.closed_loop.harness import Step, steps

pytestmark = pytest.mark.closed_loop
ROUTE = "examples/routes/town_block_loop.toml"
LINE_X_M = 190.0
ZONE_END_Y_M = 110.0
NO_RIDERS = PassengerConfig(arrivals_per_stop_per_min=0.0, initial_waiting={})
EAST_AVE_NORTH_END = 211
"""East Avenue's southbound lanelet at the map's northern edge."""


@dataclasses.dataclass
class Passage:
    """What the shuttle did at the line, and where the car was when it crossed."""

    stood_s: float = 0.0
    min_speed_before_mps: float = np.inf
    car_y_at_crossing_m: float | None = None
    crossed: bool = False
    reasons: set[str] = dataclasses.field(default_factory=set)
    give_way_reasons: set[str] = dataclasses.field(default_factory=set)
    last: Step | None = None


def _drive(scenario: Scenario) -> Passage:
    p = Passage()
    prev_t = 0.0

    def through(step: Step) -> bool:
        fx, fy = step.sim.world.ego_front()
        return fy < 100.0 and fx > 195.0  # well into East Ave after the turn

    for step in steps(scenario, until=through):
        p.last = step
        w = step.sim.world
        fx, _ = w.ego_front()
        speed = w.ego.state.speed_mps
        d = step.out.decision
        if d is not None and fx < LINE_X_M:
            p.reasons.add(d.reason)
            if d.stop_reason is StopReason.GIVE_WAY:
                p.give_way_reasons.add(d.reason)
        if LINE_X_M - 15.0 < fx < LINE_X_M:
            p.min_speed_before_mps = min(p.min_speed_before_mps, speed)
            if fx > LINE_X_M - 4.0 and speed < 0.1:
                p.stood_s += step.t_s - prev_t
        if not p.crossed and fx >= LINE_X_M:
            p.crossed = True
            cars = [a.y_m for a in w.agents if a.active and a.cls.name == "CAR" and a.x_m < 200.0]
            p.car_y_at_crossing_m = min(cars) if cars else None
        prev_t = step.t_s
    return p


def _incidents(p: Passage) -> list[object]:
    assert p.last is not None
    return [e for e in p.last.sim.judge.events if e[1] in ("collision", "takeover", "rule_violation")]


def _scenario(start_s_m: float, cars: tuple[MapCar, ...]) -> Scenario:
    return Scenario(
        name="give_way",
        minutes=0.5,
        start_route_s_m=start_s_m,
        map=MapSpec(name="route", route=ROUTE),
        passengers=NO_RIDERS,
        map_cars=cars,
    )


def _car(spawn_t_s: float) -> tuple[MapCar, ...]:
    return (MapCar(spawn_t_s=spawn_t_s, speed_mps=8.0, from_lanelet=EAST_AVE_NORTH_END, distance_m=150.0),)


def test_the_shuttle_waits_at_the_give_way_line_for_a_car_on_the_priority_road() -> None:
    p = _drive(_scenario(240.0, _car(3.0)))
    assert p.crossed, "never crossed the line"
    assert p.stood_s > 1.0, f"did not wait at the line (stood {p.stood_s:.1f} s)"
    # The car had cleared the conflict zone before the shuttle's front crossed the line.
    assert p.car_y_at_crossing_m is None or p.car_y_at_crossing_m < ZONE_END_Y_M, p.car_y_at_crossing_m
    assert any("give way to 1 road user at North St / East Ave" in r for r in p.give_way_reasons)
    assert _incidents(p) == []


def test_an_empty_priority_road_is_crossed_without_a_full_stop() -> None:
    p = _drive(_scenario(220.0, ()))
    assert p.crossed
    assert p.min_speed_before_mps > 1.0, p.min_speed_before_mps
    # The rule judged the gap (and found it free): not a line driven over blind.
    assert any("give way at North St / East Ave: gap" in r for r in p.reasons), p.reasons
    assert p.last is not None
    entries = [e[2] for e in p.last.sim.judge.events if e[1] == "give_way_entry"]
    assert entries and entries[0]["stopped_before"] is False
    assert _incidents(p) == []


def _give_way_line_made_a_stop_sign(spec: MapSpec) -> ServiceRoute:
    """The town as the stack and the simulator load it, its give-way line a two-way stop's instead."""
    service = load_route(spec.route)
    lines = tuple(
        dataclasses.replace(sl, right_of_way_id=None, stop_sign_id=1) if sl.right_of_way_id else sl
        for sl in service.hdmap.stop_lines
    )
    hdmap = dataclasses.replace(service.hdmap, stop_lines=lines, right_of_way_rules=())
    return dataclasses.replace(service, hdmap=hdmap)


def test_after_a_two_way_stops_full_stop_the_shuttle_waits_for_the_gap(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(closed_loop, "load_world_map", _give_way_line_made_a_stop_sign)
    # The car comes into view as the shuttle stands its full stop, a few seconds from the zone.
    p = _drive(_scenario(240.0, _car(6.0)))
    assert p.crossed, "never crossed the line"
    assert p.car_y_at_crossing_m is None or p.car_y_at_crossing_m < ZONE_END_Y_M, p.car_y_at_crossing_m
    assert p.stood_s > 2.0  # the full stop, then the wait for the gap
    assert any("stop for stop sign 961: stop" in r for r in p.reasons), p.reasons
    assert any("stop sign 961: give way to 1 road user" in r for r in p.give_way_reasons), p.give_way_reasons
    assert _incidents(p) == []
