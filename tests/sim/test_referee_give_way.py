"""The referee at the example town's give-way line (North St yields to East Ave at x = 190; the route
turns right into East Ave's southbound lane, whose conflict zone with the turn starts at y = 117.4).

The shuttle's front is moved along North Street and round the turn by hand; a car stands in for the
priority traffic on the southbound lane (x = 198.25)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.object_class import ObjectClass
from lastmile.core.run_events import EventKind
from lastmile.evaluation.report_tables import yield_lines_table
from lastmile.hdmap.service_route import ServiceRoute, load_route
from lastmile.sim.agents import Agent
from lastmile.sim.give_way_referee import GiveWayReferee, stopping_sight_distance_m
from tests.evaluation.synthetic import make_log

ROUTE = Path(__file__).resolve().parents[2] / "examples" / "routes" / "town_block_loop.toml"
SOUTHBOUND_X_M, ZONE_START_Y_M = 198.25, 117.4


@pytest.fixture(scope="module")
def service() -> ServiceRoute:
    return load_route(ROUTE)


def _car(y_m: float, speed_mps: float) -> Agent:
    return Agent(
        id=5,
        cls=ObjectClass.CAR,
        x_m=SOUTHBOUND_X_M,
        y_m=y_m,
        yaw_rad=-math.pi / 2,
        speed_mps=speed_mps,
        length_m=4.5,
        width_m=1.8,
        rcs_dbsm=10.0,
    )


def _drive(service: ServiceRoute, car: Agent, stand_s: float = 0.0) -> list[tuple[str, dict[str, object]]]:
    """The front along the route from 20 m before the line to 20 m past it, 0.1 m per 0.05 s tick,
    standing ``stand_s`` 1 m before the line; the car stays where it is (what matters is the moment
    of entry)."""
    referee = GiveWayReferee(service.hdmap, service.polyline)
    (j,) = referee.junctions
    events: list[tuple[str, dict[str, object]]] = []
    t = 0.0
    for ahead in np.arange(20.0, -20.0, -0.1):
        speed = 2.0
        if abs(ahead - 1.0) < 0.05:
            for _ in range(int(stand_s / 0.05)):
                x, y, _ = service.polyline.point_at(j.line_s_m - ahead)
                events += referee.step(t, (x, y), 0.0, [car])
                t += 0.05
        x, y, _ = service.polyline.point_at(j.line_s_m - ahead)
        events += referee.step(t, (x, y), speed, [car])
        t += 0.05
    return events


def test_the_stopping_sight_distance_is_aashtos() -> None:
    # 30 km/h: 2.5 s at 8.33 m/s plus 8.33^2 / (2 x 3.4): 20.8 + 10.2 m.
    assert stopping_sight_distance_m(30 / 3.6) == pytest.approx(31.05, abs=0.05)
    assert stopping_sight_distance_m(0.0) == 0.0


def test_entering_the_zone_with_a_car_inside_its_stopping_distance_is_a_failure_to_yield(
    service: ServiceRoute,
) -> None:
    near = _car(ZONE_START_Y_M + 2.25 + 20.0, 8.0)  # 20 m away at 8 m/s: it needs 30.7 m to stop
    events = _drive(service, near)
    failures = [d for k, d in events if k is EventKind.RULE_VIOLATION and d["rule"] == "failure_to_yield"]
    assert len(failures) == 1 and "car 5 20.0 m from the conflict zone" in str(failures[0]["detail"])


def test_a_car_that_can_still_stop_or_stands_away_from_the_zone_is_no_failure(service: ServiceRoute) -> None:
    for car in (_car(ZONE_START_Y_M + 2.25 + 40.0, 8.0), _car(ZONE_START_Y_M + 2.25 + 5.0, 0.0)):
        assert not [d for k, d in _drive(service, car) if k is EventKind.RULE_VIOLATION]


def test_a_car_standing_in_the_zone_is_a_failure_to_yield(service: ServiceRoute) -> None:
    events = _drive(service, _car(ZONE_START_Y_M - 3.0, 0.0))
    assert any(
        k is EventKind.RULE_VIOLATION
        and d["rule"] == "failure_to_yield"
        and "in the conflict zone" in str(d["detail"])
        for k, d in events
    )


def test_each_passage_of_the_line_says_whether_the_shuttle_stood_before_it(service: ServiceRoute) -> None:
    far = _car(ZONE_START_Y_M + 100.0, 0.0)
    rolled = [d for k, d in _drive(service, far) if k is EventKind.GIVE_WAY_ENTRY]
    stood = [d for k, d in _drive(service, far, stand_s=3.0) if k is EventKind.GIVE_WAY_ENTRY]
    assert rolled == [
        {
            "stop_line_id": rolled[0]["stop_line_id"],
            "line_kind": "give_way",
            "stopped_before": False,
            "stood_s": 0.0,
        }
    ]
    assert stood[0]["stopped_before"] is True and stood[0]["stood_s"] == pytest.approx(3.0, abs=0.1)


def test_the_report_lists_each_passage_of_a_yield_line() -> None:
    assert yield_lines_table(make_log(np.full(100, 2.0))) == []
    events = [
        (
            12.0,
            "give_way_entry",
            {"stop_line_id": 961, "line_kind": "give_way", "stopped_before": False, "stood_s": 0.0},
        ),
        (
            80.0,
            "give_way_entry",
            {"stop_line_id": 961, "line_kind": "stop_sign", "stopped_before": True, "stood_s": 6.3},
        ),
    ]
    rows = [r for r in yield_lines_table(make_log(np.full(100, 2.0), events=events)) if r.startswith("| ")]
    assert rows[1:] == ["| 12.0 | 961 | give_way | no | 0.0 |", "| 80.0 | 961 | stop_sign | yes | 6.3 |"]
