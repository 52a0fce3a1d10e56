"""The run configuration: TOML in, strict checks, one clear line from the CLI, and recorded in every run."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.errors import ConfigError
from lastmile.core.perception_mode import PerceptionMode
from lastmile.runner.closed_loop import evaluate_run, run_scenario
from lastmile.runner.run_config import RunConfig, load_run_config, run_config_to_toml
from lastmile.sim.scenario import Scenario, load_scenario

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _one_line_exit_2(args: list[str], expected: str) -> None:
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], result.output


def test_the_example_configuration_loads_and_round_trips_through_toml(tmp_path: Path) -> None:
    config = load_run_config(EXAMPLES / "configs" / "radar_pure_pursuit.toml")
    assert config.stack.perception is PerceptionMode.RADAR_TRACKING
    assert config.stack.lateral_controller == "pure_pursuit" and config.stack.cruise_speed_mps == 4.0
    path = tmp_path / "again.toml"
    path.write_text(run_config_to_toml(config))
    assert load_run_config(path) == config
    default = tmp_path / "default.toml"
    default.write_text(run_config_to_toml(RunConfig()))
    assert load_run_config(default) == RunConfig()


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[stack]\nplanner_speed = 3\n", "unknown key 'planner_speed'"),
        ('[stack]\nlateral_controller = "stanley_typo"\n', "stack.lateral_controller: expected one of"),
        ('[stack]\nplanner = "lattice_typo"\n', "stack.planner: expected one of"),
        ('[stack]\nperception = "oracle"\n', "expected one of ['lidar_camera_radar', 'radar_tracking']"),
        ("[loop]\ntick_us = 3000\n", "loop.tick_us: expected a divisor of 10000"),
        ("[stack.safety]\nmrm_decel_mps2 = 9.0\n", "stack.safety.mrm_decel_mps2: expected a value in"),
        (
            '[stack]\nlocalization = "landmarks"\nperception = "radar_tracking"\n',
            "stack.localization 'landmarks': expected raw LiDAR perception",
        ),
        (
            "[stack.path.passing]\nclearance_m = 1.2\n",
            "stack.path.passing.clearance_m: expected the same as stack.decision.passing.clearance_m",
        ),
        ("[stack.decision.passing]\nwait_gap_m = -1.0\n", "passing.wait_gap_m: expected a positive number"),
    ],
)
def test_a_bad_configuration_is_one_line_and_exit_2(tmp_path: Path, text: str, expected: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"expected|unknown"):
        load_run_config(path)
    _one_line_exit_2(
        ["run", "--minutes", "0.05", "--config", str(path), "--out", str(tmp_path / "o")], expected
    )
    assert not (tmp_path / "o").exists()  # refused before any work


def test_a_perception_mode_the_scenario_cannot_serve_is_refused_before_the_run(tmp_path: Path) -> None:
    scenario = EXAMPLES / "scenarios" / "snow_cover.toml"
    assert load_scenario(scenario).snow_cover_lane_m > 0
    out = tmp_path / "o"
    _one_line_exit_2(
        ["run", "--scenario", str(scenario), "--perception", "radar", "--out", str(out)],
        "perception 'radar_tracking' cannot serve scenario 'snow_cover'",
    )
    assert not out.exists()


def test_the_landmarks_mode_with_radar_perception_from_the_command_line_is_refused(tmp_path: Path) -> None:
    # Radars give object lists only: nothing to find poles and facades in.
    path = EXAMPLES / "configs" / "landmarks.toml"
    stack = load_run_config(path).stack
    assert stack.localization == "landmarks" and stack.perception is PerceptionMode.LIDAR_CAMERA_RADAR
    out = tmp_path / "o"
    _one_line_exit_2(
        ["run", "--config", str(path), "--perception", "radar", "--out", str(out)],
        "'landmarks': expected raw LiDAR perception 'lidar_camera_radar', got perception 'radar_tracking'",
    )
    assert not out.exists()


def test_a_scenario_carrying_a_vehicle_setting_says_where_it_belongs(tmp_path: Path) -> None:
    path = tmp_path / "old.toml"
    path.write_text("cruise_speed_mps = 3.0\n")
    _one_line_exit_2(["run", "--scenario", str(path), "--out", str(tmp_path / "o")], "is a vehicle setting")


def test_every_run_records_the_configuration_that_produced_it(tmp_path: Path) -> None:
    config = load_run_config(EXAMPLES / "configs" / "radar_pure_pursuit.toml")
    log = run_scenario(Scenario(name="short", minutes=0.05), config)
    evaluate_run(log, tmp_path)
    doc = json.loads((tmp_path / "metrics.json").read_text())
    assert doc["perception_mode"] == "radar_tracking"
    recorded = doc["configuration"]["run_config"]
    assert recorded["stack"]["lateral_controller"] == "pure_pursuit"
    assert recorded["stack"]["cruise_speed_mps"] == 4.0 and recorded["loop"]["tick_us"] == 10_000
    assert doc["configuration"]["name"] == "short"  # and the scenario beside it


def test_the_lateral_controller_of_the_configuration_is_the_one_that_drives() -> None:
    # Two controllers, same world and seed: the traces differ, so the setting reached the stack.
    base = RunConfig().with_perception(PerceptionMode.RADAR_TRACKING)
    pursuit = dataclasses.replace(
        base, stack=dataclasses.replace(base.stack, lateral_controller="pure_pursuit")
    )
    scenario = Scenario(name="short", minutes=0.3)
    a, b = run_scenario(scenario, base), run_scenario(scenario, pursuit)
    assert (a.column("steer_front_rad") != b.column("steer_front_rad")).any()


def test_ctrl_c_ends_the_run_early_and_keeps_what_was_done(tmp_path: Path) -> None:
    def interrupt(done_s: float, total_s: float) -> None:
        if done_s >= 5.0:
            raise KeyboardInterrupt

    config = RunConfig().with_perception(PerceptionMode.RADAR_TRACKING)
    log = run_scenario(Scenario(name="short", minutes=0.5), config, progress=interrupt)
    assert log.timing["interrupted"] is True
    t = log.column("t_s")
    assert 4.9 < t[-1] < 5.1  # the ticks up to the interrupt are all there
    evaluate_run(log, tmp_path)
    doc = json.loads((tmp_path / "metrics.json").read_text())
    assert 4.9 < doc["duration_s"] <= 5.1 and (tmp_path / "report.md").exists()
