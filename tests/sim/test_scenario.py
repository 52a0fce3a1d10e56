import pytest

from lastmile.core.errors import ConfigError
from lastmile.sim.scenario import default_service, load_scenario


def test_a_scenario_file_round_trips_into_typed_values(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(
        'name = "goose"\nminutes = 2\nweather = "snow"\n'
        '[[walkers]]\nkind = "goose"\nroute_s_m = 300\nspeed_mps = 0.3\n'
        "[passengers]\ninitial_waiting = { S1 = 2 }\n"
    )
    s = load_scenario(p)
    assert s.minutes == 2.0 and s.weather == "snow"
    assert s.walkers[0].kind == "goose" and s.walkers[0].speed_mps == 0.3
    assert s.passengers.initial_waiting == {"S1": 2}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('weather = "hail"\n', "expected one of"),
        ("minutes = -1\n", r"scenario.minutes: expected a value in"),
        ("speed = 3\n", "unknown key 'speed'"),
        ('[[walkers]]\nkind = "dragon"\n', "expected one of \\['pedestrian', 'goose'\\]"),
        ('lateral_controller = "stanley"\n', "is a vehicle setting: expected it in a run configuration"),
        ("minutes = \n", "expected valid TOML"),
    ],
)
def test_a_broken_scenario_file_says_what_was_expected(tmp_path, text, message):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_scenario(p)


def test_default_service_has_every_ingredient_the_issue_names():
    s = default_service(seed=3)
    assert s.seed == 3 and s.minutes == 10.0
    assert set(s.passengers.initial_waiting) == {"S1", "S2", "S3", "S4"}
    assert s.parked_cars and s.crosswalk_pedestrians and s.side_road_cars and s.ring_cars
    assert {w.kind for w in s.walkers} == {"pedestrian", "goose"}
