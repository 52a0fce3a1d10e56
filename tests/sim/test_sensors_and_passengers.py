import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.rng import component_rng
from lastmile.sim.passengers import PassengerConfig, PassengerModel, StopVisit
from lastmile.sim.sensors import RCS_DBSM, detection_probability
from lastmile.sim.weather import parse_weather


def test_small_targets_fade_before_large_ones():
    goose, car = RCS_DBSM[ObjectClass.ANIMAL], RCS_DBSM[ObjectClass.CAR]
    assert detection_probability(goose, 15.0, 100.0) > 0.5
    assert detection_probability(goose, 40.0, 100.0) == 0.0
    assert detection_probability(car, 40.0, 100.0) > 0.9


def test_unknown_weather_names_the_choices():
    with pytest.raises(ConfigError, match="expected one of"):
        parse_weather("hail")


def test_riders_board_one_at_a_time_and_press_the_seat_button(straight_map):
    model = PassengerModel(
        straight_map.stops, PassengerConfig(initial_waiting={"S1": 2}), component_rng(0, "p"), seats=6
    )
    assert model.new_calls == [("S1", "stop_button")]
    model.visit = StopVisit(
        stop_id="S1", opened_s=0.0, curb_gap_m=0.1, body_gap_m=0.1, longitudinal_error_m=0.0
    )
    events = []
    t = 0.0
    while t < 12.0:
        events += model.step_door(t, 0.01, door_cmd_open=True, at_stop="S1", stopped=True)
        t += 0.01
    kinds = [k for k, _ in events]
    assert kinds == ["passenger_boarded", "passenger_boarded"]
    assert len(model.onboard) == 2 and not model.waiting["S1"]
    assert model.visit.boarded == 2
    assert ("S2", "seat_button") in model.new_calls


def test_door_does_not_open_while_moving(straight_map):
    model = PassengerModel(straight_map.stops, PassengerConfig(), component_rng(0, "p"), seats=6)
    for _ in range(500):
        model.step_door(0.0, 0.01, door_cmd_open=True, at_stop=None, stopped=False)
    assert model.door_position == 0.0


def test_initial_riders_at_an_unknown_stop_are_a_config_error(straight_map):
    with pytest.raises(ConfigError, match="expected stop ids"):
        PassengerModel(
            straight_map.stops, PassengerConfig(initial_waiting={"X9": 1}), component_rng(0, "p"), 6
        )


def test_poisson_arrivals_match_the_rate(straight_map):
    model = PassengerModel(
        straight_map.stops, PassengerConfig(arrivals_per_stop_per_min=2.0), component_rng(1, "p"), seats=6
    )
    model.step_arrivals(3600.0)
    n = len(model.waiting["S1"])
    assert abs(n - 120) < 4 * np.sqrt(120)


def test_a_map_with_one_stop_cannot_host_riders(straight_map):
    with pytest.raises(ConfigError, match="at least 2 stops"):
        PassengerModel(straight_map.stops[:1], PassengerConfig(), component_rng(0, "p"), seats=6)


def test_a_visit_ends_as_the_door_closes_with_the_riders_left_waiting(straight_map):
    # One seat, three riders: one boards, two are left; a fourth arriving later is counted too.
    model = PassengerModel(
        straight_map.stops, PassengerConfig(initial_waiting={"S1": 3}), component_rng(0, "p"), seats=1
    )
    model.visit = StopVisit(
        stop_id="S1", opened_s=0.0, curb_gap_m=0.1, body_gap_m=0.05, longitudinal_error_m=0.2
    )
    t = 0.0
    while t < 10.0:
        model.step_door(t, 0.01, door_cmd_open=True, at_stop="S1", stopped=True)
        t += 0.01
    assert model.end_visit() is None  # the door is still open
    model._add("S1", t)
    while model.door_position > 0.0:
        model.step_door(t, 0.01, door_cmd_open=False, at_stop="S1", stopped=True)
        t += 0.01
    served = model.end_visit()
    assert served == {
        "stop_id": "S1",
        "curb_gap_m": 0.1,
        "body_gap_m": 0.05,
        "longitudinal_error_m": 0.2,
        "boarded": 1,
        "alighted": 0,
        "left_waiting": 3,
        "seats_free": 0,
    }
    assert model.visit is None and model.end_visit() is None
