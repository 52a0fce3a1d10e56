import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.vehicle_messages import BehaviourState
from lastmile.evaluation.metrics import compute_metrics
from lastmile.recorder.replay import read_recording
from lastmile.runner.closed_loop import run_scenario
from lastmile.runner.run_config import load_run_config
from lastmile.runner.sweep import CHECKS, SWEEP_CONFIG, generic_cases, run_sweep
from lastmile.safety.supervisor import SafetySupervisor
from lastmile.sim.faults import FAULT_MENU
from lastmile.sim.scenario import load_scenario
from lastmile.sim.scenario_generator import ScenarioSpace, sample_scenarios
from lastmile.sim.suites import FAULT_CHECKS, GENERIC_CHECKS, SHUTTLE_SPEEDS_MPS, WEATHERS, iso22737_suite
from lastmile.stack.shuttle_stack import ShuttleStack

SHORT = ScenarioSpace(minutes=0.3, fault_start_s=(2.0, 5.0), fault_duration_s=(2.0, 5.0))


def test_generated_scenarios_repeat_from_their_seed_and_round_trip_through_toml(tmp_path):
    first = sample_scenarios(SHORT, 12, seed=4)
    assert first == sample_scenarios(SHORT, 12, seed=4)
    assert first != sample_scenarios(SHORT, 12, seed=5)
    assert len({s.seed for s in first}) == 12
    cases = generic_cases(first)
    from lastmile.runner.sweep import write_cases

    for case, path, config_path in write_cases(cases, tmp_path):
        assert load_scenario(path) == dataclasses.replace(case.scenario, checks=case.checks)
        assert load_run_config(config_path) == SWEEP_CONFIG


def test_local_sweep_writes_a_summary_row_per_scenario(tmp_path):
    cases = generic_cases(sample_scenarios(SHORT, 3, seed=1))
    summary = run_sweep(cases, tmp_path, engine="local", workers=2)
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk == summary
    assert {"scenarios", "passed", "failed", "collisions_at_fault", "rows"} <= set(summary)
    assert summary["scenarios"] == 3 and summary["passed"] + summary["failed"] == 3
    assert [r["name"] for r in summary["rows"]] == [c.name for c in cases]
    for row in summary["rows"]:
        assert (tmp_path / "scenarios" / f"{row['name']}.toml").exists()
        assert tuple(row["checks"]) == (FAULT_CHECKS if row["faults"] else GENERIC_CHECKS)


def test_ray_and_local_engines_give_identical_outcomes(tmp_path, monkeypatch):
    pytest.importorskip("ray", reason="the ray extra is not installed")
    # Ray runs its workers at nice 15 so its driver stays responsive; beside the suite's other
    # worker's closed-loop runs (nice 0) they got about 5 % of a core each, and this test took
    # 271-434 s instead of 21 s. The same priority as the local pool is a fair comparison.
    monkeypatch.setenv("RAY_worker_niceness", "0")
    cases = generic_cases(sample_scenarios(SHORT, 3, seed=7))
    local = run_sweep(cases, tmp_path / "local", engine="local", workers=2)
    remote = run_sweep(cases, tmp_path / "ray", engine="ray")
    strip = lambda rows: [  # noqa: E731
        {k: v for k, v in r.items() if k not in ("scenario_file", "config_file")} for r in rows
    ]
    assert strip(local["rows"]) == strip(remote["rows"])


def test_a_stack_raising_on_every_tick_is_stopped_by_the_loops_safety_and_the_black_box_written(
    monkeypatch, tmp_path
):
    real_tick = ShuttleStack.tick

    def tick(self, now, frames, safety=None):
        if int(now) >= 20_000_000:
            raise RuntimeError("segfault in planning")
        return real_tick(self, now, frames, safety)

    monkeypatch.setattr(ShuttleStack, "tick", tick)
    scenario = dataclasses.replace(sample_scenarios(SHORT, 1, seed=2)[0], minutes=0.6, faults=())
    log = run_scenario(scenario, SWEEP_CONFIG, black_box_dir=tmp_path)
    crashes = log.events_of("stack_crash")
    assert len(crashes) == 1 and crashes[0].t_s == 20.0 and "segfault" in crashes[0].data["error"]
    # The loop's safety answers on the tick of the crash: an emergency stop, no waiting for the watchdog.
    level = next(e for e in log.events_of("safety") if e.t_s >= 20.0)
    assert level.t_s == 20.0 and level.data["level"] == "EMERGENCY_STOP", level
    assert "vehicle software failed" in level.data["reason"]
    t, v = log.column("t_s"), log.column("speed_mps")
    assert v[t < 20.0].max() > 2.0  # it was driving
    assert v[-1] < 0.05  # and the safety's brake stopped it
    crash_files = [e for e in log.events_of("recording") if e.data["trigger"] == "crash"]
    assert len(crash_files) == 1 and (tmp_path / Path(str(crash_files[0].data["path"])).name).exists()
    rec = read_recording(Path(str(crash_files[0].data["path"])))
    assert rec.span_us[1] >= 19_990_000  # the window runs up to the crash


def test_a_stack_that_hangs_trips_the_hardware_watchdog_and_the_shuttle_stops(monkeypatch):
    """A frozen control loop: the stack keeps returning its last output (stale command stamps)."""
    real_tick = ShuttleStack.tick
    frozen: dict[str, object] = {}

    def tick(self, now, frames, safety=None):
        if int(now) < 20_000_000:
            frozen["out"] = real_tick(self, now, frames, safety)
        return frozen["out"]

    monkeypatch.setattr(ShuttleStack, "tick", tick)
    scenario = dataclasses.replace(sample_scenarios(SHORT, 1, seed=2)[0], minutes=0.6, faults=())
    log = run_scenario(scenario, SWEEP_CONFIG)
    trips = log.events_of("hardware_watchdog")
    assert len(trips) == 1 and 20.09 <= trips[0].t_s <= 20.12, trips  # 100 ms without a fresh command
    assert not log.events_of("stack_crash")
    t, v = log.column("t_s"), log.column("speed_mps")
    assert v[t < 20.0].max() > 2.0 and v[-1] < 0.05


def test_the_iso22737_suite_covers_the_plan():
    cases = iso22737_suite()
    names = [c.name for c in cases]
    assert len(names) == len(set(names))
    for hazard in (
        "stationary_obstacle_in_lane",
        "pedestrian_crossing_clear_view",
        "pedestrian_behind_parked_vehicle",
        "cyclist_merging",
        "car_turning_in",
    ):
        for weather in WEATHERS:
            for speed in SHUTTLE_SPEEDS_MPS:
                assert f"{hazard}_{weather}_{round(speed * 3.6)}kph" in names
    faults = {
        (f.kind, f.target)
        for c in cases
        if c.group == "minimal risk manoeuvre on faults"
        for f in c.scenario.faults
    }
    assert faults == set(FAULT_MENU)
    estops = {c.scenario.estop_in_state for c in cases if c.group == "emergency stop from every state"}
    assert estops == {s.value for s in BehaviourState}
    assert {c.group for c in cases} >= {
        "hazard, clear view",
        "hazard, occluded view",
        "minimal risk manoeuvre on faults",
        "staying in the drivable area",
        "emergency stop from every state",
    }


def _estop_case(state: str, minutes: float):
    case = next(c for c in iso22737_suite() if c.name == f"estop_from_{state}")
    return case, dataclasses.replace(case.scenario, minutes=minutes)


def test_operator_estop_while_cruising_stops_the_shuttle_and_holds_it_until_release():
    _case, scenario = _estop_case("normal_driving", 1.0)
    log = run_scenario(scenario, SWEEP_CONFIG)
    result = CHECKS["estop_honoured"](log, compute_metrics(log))
    assert result.ok, result.detail
    press = log.events_of("operator_estop")[0]
    t, v = log.column("t_s"), log.column("speed_mps")
    assert v[np.searchsorted(t, press.t_s)] >= 4.0  # pressed at cruise, not at the start line
    assert next(e.data["level"] for e in log.events_of("safety") if e.t_s >= press.t_s) == "EMERGENCY_STOP"
    release = log.events_of("operator_release")[0]
    assert v[t > release.t_s + 5.0].max() > 1.0  # released, it drives on


def test_estop_check_fails_when_the_stack_ignores_the_button(monkeypatch):
    monkeypatch.setattr(SafetySupervisor, "operator_emergency_stop", lambda self, now_us, reason: None)
    _, scenario = _estop_case("normal_driving", 0.8)
    log = run_scenario(scenario, SWEEP_CONFIG)
    result = CHECKS["estop_honoured"](log, compute_metrics(log))
    assert not result.ok and "EMERGENCY_STOP" in result.detail


def test_estop_check_fails_when_the_state_is_never_reached():
    # The encounter scenarios carry no riders: the shuttle never onboards.
    base = next(c for c in iso22737_suite() if c.group == "hazard, clear view").scenario
    log = run_scenario(dataclasses.replace(base, minutes=0.3, estop_in_state="onboarding"), SWEEP_CONFIG)
    result = CHECKS["estop_honoured"](log, compute_metrics(log))
    assert not result.ok and "never reached state 'onboarding'" in result.detail


def test_sweep_cli_rejects_two_sources_in_one_line(tmp_path):
    result = CliRunner().invoke(
        app, ["sweep", "--suite", "iso22737", "--generate", "3", "--out", str(tmp_path)]
    )
    assert result.exit_code == 2
    assert "expected exactly one of --suite, --generate, --scenarios" in result.output
    result = CliRunner().invoke(app, ["sweep", "--suite", "nope", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "expected one of ['iso22737']" in result.output


def test_an_unknown_perception_mode_is_one_line_and_exit_2(tmp_path):
    for command in (["run", "--minutes", "0.1"], ["sweep", "--suite", "iso22737"]):
        result = CliRunner().invoke(app, [*command, "--perception", "oracle", "--out", str(tmp_path)])
        assert result.exit_code == 2
        assert "--perception: expected one of ['lidar', 'radar'], got 'oracle'" in result.output
        assert len(result.output.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir())  # nothing was run or written
