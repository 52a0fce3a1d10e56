"""Riders who press the drop-off button (Snow Lion's unscheduled drop-off) in the passenger model, the
scenario file and the metrics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.rng import component_rng
from lastmile.evaluation import metrics as m
from lastmile.evaluation.report_tables import drop_offs_table
from lastmile.sim.passengers import PassengerConfig, PassengerModel, StopVisit
from lastmile.sim.scenario import DropOffRequest, Scenario, load_scenario, scenario_to_toml
from tests.evaluation.synthetic import make_log

NOBODY = PassengerConfig(arrivals_per_stop_per_min=0.0)


def _door(model: PassengerModel, at_stop: str | None, seconds: float = 6.0) -> list:
    events, t = [], 0.0
    while t < seconds:
        events += model.step_door(t, 0.01, door_cmd_open=True, at_stop=at_stop, stopped=True)
        t += 0.01
    for _ in range(300):  # and closed again
        model.step_door(t, 0.01, door_cmd_open=False, at_stop=at_stop, stopped=True)
    return events


def test_a_drop_off_rider_stays_on_until_the_press_then_gets_off_at_the_kerb(straight_map) -> None:
    model = PassengerModel(straight_map.stops, NOBODY, component_rng(0, "p"), 6, drop_off_times_s=(30.0,))
    assert len(model.onboard) == 1 and model.press_due(29.9) == []
    # Before the press the door opens at a stop and at the kerb: nobody gets off.
    model.visit = StopVisit(
        stop_id="S1", opened_s=0.0, curb_gap_m=0.2, body_gap_m=0.2, longitudinal_error_m=0.0
    )
    assert _door(model, "S1") == [] and _door(model, None) == []
    assert model.press_due(30.0) == [(1, 0)]
    events = _door(model, None)
    assert [k for k, _ in events] == ["passenger_alighted"] and events[0][1]["stop_id"] == ""
    assert not model.onboard and model.drop_off_alightings == [(1, None)]


def test_a_drop_off_rider_gets_off_at_a_stop_when_the_door_opens_there_first(straight_map) -> None:
    model = PassengerModel(straight_map.stops, NOBODY, component_rng(0, "p"), 6, drop_off_times_s=(0.0,))
    model.press_due(0.0)
    model.visit = StopVisit(
        stop_id="S2", opened_s=0.0, curb_gap_m=0.2, body_gap_m=0.2, longitudinal_error_m=0.0
    )
    events = _door(model, "S2")
    assert [d["stop_id"] for _, d in events] == ["S2"] and model.drop_off_alightings == [(1, "S2")]


def test_more_drop_off_riders_than_seats_is_one_clear_line(straight_map) -> None:
    with pytest.raises(ConfigError, match="at most 2 riders on board"):
        PassengerModel(straight_map.stops, NOBODY, component_rng(0, "p"), 2, drop_off_times_s=(1.0, 2.0, 3.0))
    with pytest.raises(ConfigError, match=r"drop_off_requests\.t_s"):
        DropOffRequest(t_s=-1.0)


def test_scenario_file_round_trips_drop_off_requests(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('name = "x"\n[[drop_off_requests]]\nt_s = 95.0\n', encoding="utf-8")
    scenario = load_scenario(path)
    assert scenario.drop_off_requests == (DropOffRequest(t_s=95.0),)
    path.write_text(scenario_to_toml(scenario), encoding="utf-8")
    assert load_scenario(path) == scenario
    assert Scenario().drop_off_requests == ()


def test_drop_off_metrics_appear_only_in_runs_with_a_request() -> None:
    plain = m.compute_metrics(make_log(np.full(100, 2.0)))
    assert not any(k.startswith("drop_off") for k in plain)
    events = [
        (1.0, "drop_off_requested", {"passenger_id": 1, "route_s_m": 10.0}),
        (
            30.0,
            "drop_off_served",
            {
                "passenger_id": 1,
                "stop_id": "",
                "curb_gap_m": 0.21,
                "body_gap_m": 0.2,
                "wait_s": 11.5,
                "route_s_m": 50.0,
            },
        ),
        (40.0, "drop_off_requested", {"passenger_id": 2, "route_s_m": 80.0}),
    ]
    out = m.compute_metrics(make_log(np.full(100, 2.0), events=events))
    assert (out["drop_offs_requested"], out["drop_offs_served"], out["drop_offs_at_kerb"]) == (2, 1, 1)
    assert out["drop_off_curb_gap_max_m"] == 0.21 and out["drop_off_wait_min_s"] == 11.5


def test_the_report_lists_each_drop_off_where_it_was_served() -> None:
    assert drop_offs_table(make_log(np.full(100, 2.0))) == []
    served = {"curb_gap_m": 0.2, "body_gap_m": 0.2, "wait_s": 11.0}
    events = [
        (1.0, "drop_off_requested", {"passenger_id": 1, "route_s_m": 10.0}),
        (20.0, "drop_off_served", {"passenger_id": 1, "stop_id": "", "route_s_m": 50.0, **served}),
        (30.0, "drop_off_requested", {"passenger_id": 2, "route_s_m": 80.0}),
        (60.0, "drop_off_served", {"passenger_id": 2, "stop_id": "S1", "route_s_m": 120.0, **served}),
        (70.0, "drop_off_requested", {"passenger_id": 3, "route_s_m": 150.0}),
    ]
    rows = [r for r in drop_offs_table(make_log(np.full(100, 2.0), events=events)) if r.startswith("| ")]
    assert len(rows) == 4  # the header and one row per request
    assert "| kerb |" in rows[1] and "| stop S1 |" in rows[2] and "not served" in rows[3]
