"""Every CLI input is checked before work starts, one line and exit 2; Ctrl-C and SIGTERM keep a run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.runner import closed_loop
from lastmile.runner.fleet_config import FleetConfig
from lastmile.runner.fleet_run import run_fleet
from lastmile.runner.loop import ClosedLoop
from lastmile.runner.stop_signals import StopSignals
from lastmile.runner.sweep import generic_cases, run_sweep, write_cases
from lastmile.sim.scenario import load_scenario
from lastmile.sim.scenario_generator import ScenarioSpace, sample_scenarios
from lastmile.sim.suites import FAULT_CHECKS, GENERIC_CHECKS, iso22737_suite

RUN = ["run", "--minutes", "0.05", "--perception", "radar", "--no-black-box"]


def _one_line_exit_2(args: list[str], expected: str) -> None:
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert expected in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output


@pytest.fixture
def no_simulation(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fails the test if a simulation starts: the inputs must be refused before any work."""

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("a simulation started although an input was bad")

    monkeypatch.setattr(closed_loop, "run_scenario", refuse)
    monkeypatch.setattr("lastmile.runner.sweep.run_sweep", refuse)


def test_a_binary_file_or_a_directory_as_scenario_is_one_line(tmp_path: Path, no_simulation: None) -> None:
    binary = tmp_path / "scenario.toml"
    binary.write_bytes(bytes(range(256)) * 4)
    _one_line_exit_2(
        [*RUN, "--scenario", str(binary), "--out", str(tmp_path / "o")],
        "expected a UTF-8 TOML text file, got binary data",
    )
    _one_line_exit_2(
        [*RUN, "--scenario", str(tmp_path), "--out", str(tmp_path / "o")],
        "expected a TOML file, got a directory",
    )


def test_out_on_a_file_or_where_no_directory_can_be_made_is_refused_before_the_run(
    tmp_path: Path, no_simulation: None
) -> None:
    a_file = tmp_path / "taken"
    a_file.write_text("x")
    _one_line_exit_2(
        [*RUN, "--out", str(a_file)], "--out: expected a directory to write into, got an existing file"
    )
    _one_line_exit_2(
        [*RUN, "--out", str(a_file / "run")], "--out: expected a directory that can be created, got"
    )
    _one_line_exit_2(
        ["sweep", "--suite", "iso22737", "--out", str(a_file)], "--out: expected a directory to write into"
    )


def test_a_negative_car_speed_in_a_scenario_is_refused(tmp_path: Path, no_simulation: None) -> None:
    scenario = tmp_path / "s.toml"
    scenario.write_text("[[ring_cars]]\nspeed_mps = -3.0\n")
    _one_line_exit_2(
        [*RUN, "--scenario", str(scenario), "--out", str(tmp_path / "o")],
        "ring_cars.speed_mps: expected a value in [0.05, 30.0], got -3.0",
    )
    scenario.write_text("[[walkers]]\ntrigger_m = 10.0\nmin_trigger_m = 20.0\n")
    _one_line_exit_2(
        [*RUN, "--scenario", str(scenario), "--out", str(tmp_path / "o")],
        "walkers.trigger_m: expected a value in [20.0, 1000.0], got 10.0",
    )


def test_sweep_with_zero_workers_is_refused_before_anything_runs(tmp_path: Path, no_simulation: None) -> None:
    _one_line_exit_2(
        ["sweep", "--suite", "iso22737", "--workers", "0", "--out", str(tmp_path / "o")],
        "sweep --workers: expected at least 1 worker process, got 0",
    )
    assert not (tmp_path / "o").exists()


def test_a_binary_detections_file_for_eval_tracking_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "0001.txt").write_text("")
    for cls in ("Car", "Pedestrian", "Cyclist"):
        (tmp_path / "det" / f"pointrcnn_{cls}").mkdir(parents=True)
        (tmp_path / "det" / f"pointrcnn_{cls}" / "0001.txt").write_bytes(b"0,1\n\xff\xfe\x00binary")
    _one_line_exit_2(
        ["eval", "tracking", "--detections", str(tmp_path / "det"), "--labels", str(tmp_path / "labels")],
        "0001.txt:2: expected detections as text, got binary data",
    )


def test_a_second_stop_signal_interrupts_at_once_and_handlers_are_restored() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with StopSignals() as stop:
        assert not stop.requested
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.requested and stop.exit_code == 143
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_stop_signal_during_a_run_leaves_the_partial_run_directory(
    signum: signal.Signals, code: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    step = ClosedLoop.step

    def step_then_signal(self: ClosedLoop, tick: int):  # type: ignore[no-untyped-def]
        if tick == 300:  # 3 s into the run: a real signal to this process, through the CLI's handler
            os.kill(os.getpid(), signum)
        return step(self, tick)

    monkeypatch.setattr(ClosedLoop, "step", step_then_signal)
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", "--minutes", "1", "--perception", "radar", "--out", str(out)])
    assert result.exit_code == code, result.output
    assert "interrupted; wrote the 3 s simulated so far" in result.output
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["duration_s"] == pytest.approx(3.01, abs=0.011)
    assert "> **Interrupted** (Ctrl-C or SIGTERM) after " in (out / "report.md").read_text()
    assert json.loads((out / "timing.json").read_text())["interrupted"] is True
    assert list((out / "recordings").glob("blackbox_manual_*.mcap"))


def test_a_stopped_sweep_keeps_finished_rows_and_names_what_did_not_run(tmp_path: Path) -> None:
    space = ScenarioSpace(minutes=0.1, fault_probability=0.0)
    cases = generic_cases(sample_scenarios(space, 3, seed=2))
    rows_done: list[int] = []
    summary = run_sweep(
        cases,
        tmp_path,
        workers=1,
        progress=lambda done, total: rows_done.append(done),
        stop=lambda: bool(rows_done),
    )
    assert summary["interrupted"] is True
    first = summary["rows"][0]
    assert first["name"] == cases[0].name and first["interrupted"] is False
    # The executor may already have handed the second case to the worker: it stops early or never runs.
    assert {r["name"] for r in summary["rows"][1:] if r["interrupted"]} | set(summary["not_run"]) == {
        c.name for c in cases[1:]
    }
    assert summary["passed"] <= 1
    assert json.loads((tmp_path / "summary.json").read_text()) == summary


def test_an_exported_suite_re_runs_with_its_own_checks_from_the_toml(tmp_path: Path) -> None:
    suite = iso22737_suite()
    write_cases(suite, tmp_path)
    reread = generic_cases([load_scenario(tmp_path / "scenarios" / f"{c.name}.toml") for c in suite])
    assert [c.checks for c in reread] == [c.checks for c in suite]
    # The suite's own checks differ from the generic ones somewhere (the e-stop and fault cases).
    assert any(c.checks not in (GENERIC_CHECKS, FAULT_CHECKS) for c in suite)


def test_a_scenario_naming_an_unknown_check_is_refused_before_the_sweep(tmp_path: Path) -> None:
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "a.toml").write_text('minutes = 0.1\nchecks = ["no_collison"]\n')
    _one_line_exit_2(
        ["sweep", "--scenarios", str(tmp_path / "s"), "--out", str(tmp_path / "o")],
        "unknown check 'no_collison'",
    )


def test_a_stopped_fleet_run_writes_its_run_directory_for_the_time_simulated(tmp_path: Path) -> None:
    ticks: list[int] = []
    config = FleetConfig(shuttles=1, minutes=1.0, seed=1, demand_per_pair_per_h=0.0, cameras=False)

    def stop() -> bool:
        ticks.append(1)
        return len(ticks) > 200

    metrics = run_fleet(config, tmp_path, stop=stop)
    assert metrics["interrupted"] is True
    assert metrics["duration_s"] == pytest.approx(2.0, abs=0.02)
    assert json.loads((tmp_path / "fleet_metrics.json").read_text())["interrupted"] is True
    assert (tmp_path / "shuttle-0" / "metrics.json").exists()
    assert list((tmp_path / "shuttle-0" / "recordings").glob("blackbox_manual_*.mcap"))


BAD_INVOCATIONS = [
    (["run", "--seed", "-1", "--out", "{tmp}/o"], "scenario.seed: expected a non-negative integer, got -1"),
    (
        ["sweep", "--generate", "0", "--out", "{tmp}/o"],
        "sweep --generate: expected at least 1 scenario, got 0",
    ),
    (
        ["sweep", "--suite", "iso22737", "--engine", "foo", "--out", "{tmp}/o"],
        "sweep --engine: expected one of",
    ),
    (
        ["sweep", "--suite", "iso22737", "--seed", "-3", "--out", "{tmp}/o"],
        "sweep --seed: expected a non-negative",
    ),
    (["sweep", "--scenarios", "{tmp}/taken", "--out", "{tmp}/o"], "expected a folder of scenario TOML files"),
    (
        ["experiment", "v2i", "--laps", "1", "--out", "{tmp}/taken"],
        "--out: expected a directory to write into",
    ),
    (["serve", "--out", "{tmp}/taken"], "--out: expected a directory to write into"),
    (
        ["eval", "tracking", "--detections", "{tmp}", "--labels", "{tmp}", "--json", "{tmp}/taken/x.json"],
        "--json: expected a directory to write into",
    ),
    (
        ["eval", "tracking", "--detections", "{tmp}", "--labels", "{tmp}", "--results", "{tmp}/taken"],
        "--results: expected a directory to write into",
    ),
    (
        ["eval", "localization", "{tmp}/taken", "--json", "{tmp}"],
        "--json: expected a file to write, got a directory",
    ),
]


@pytest.mark.parametrize(
    ("args", "expected"), BAD_INVOCATIONS, ids=[" ".join(a[:2]) for a, _ in BAD_INVOCATIONS]
)
def test_every_bad_option_is_one_line_before_any_work(
    args: list[str], expected: str, tmp_path: Path, no_simulation: None
) -> None:
    (tmp_path / "taken").write_text("x")
    _one_line_exit_2([a.replace("{tmp}", str(tmp_path)) for a in args], expected)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["run", "--minutes", "abc"], "python -m lastmile run: Invalid value for '--minutes'"),
        (["run", "--bogus"], "python -m lastmile run: No such option: --bogus"),
        (["bogus"], "python -m lastmile: No such command 'bogus'."),
    ],
)
def test_clicks_own_usage_errors_are_one_line_too(args: list[str], expected: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    proc = subprocess.run(
        [sys.executable, "-m", "lastmile", *args], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith(expected) and len(proc.stderr.strip().splitlines()) == 1
