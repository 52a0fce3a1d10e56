"""What a new user meets first: help with defaults, --version, python -m, LICENSE, examples, the API."""

from __future__ import annotations

import dataclasses
import itertools
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from typer.testing import CliRunner

import lastmile
from lastmile.cli import app

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def test_help_shows_the_defaults_and_the_choices() -> None:
    out = CliRunner().invoke(app, ["run", "--help"], terminal_width=200).output
    for shown in ("[default: 10]", "[default: 0]", "[default: clear]", "[default: runs/latest]"):
        assert shown in out
    assert "clear, rain, snow or fog" in out and "lidar:" in out and "radar:" in out
    out = CliRunner().invoke(app, ["sweep", "--help"], terminal_width=200).output
    assert "[default: all cores]" in out and "local (process pool) or ray" in out


def test_version_flag_and_python_dash_m() -> None:
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.strip() == lastmile.__version__
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    proc = subprocess.run(
        [sys.executable, "-m", "lastmile", "--version"], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 0 and proc.stdout.strip() == lastmile.__version__


def test_the_license_file_is_the_license_pyproject_declares() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "Apache-2.0" and project["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text


def _example_runs() -> list[tuple[str, list[str]]]:
    """One short run per example file. The scenario and configuration examples share runs (each
    scenario with the first configuration, in the perception mode it needs): every run costs the stack's
    start-up, and the suite's time is counted."""
    quick = ["--minutes", "0.01"]
    configs = sorted(EXAMPLES.glob("configs/*.toml"))
    scenarios = sorted(EXAMPLES.glob("scenarios/*.toml"))
    runs = [
        (f"scenario {s.name} with config {c.name}", ["--scenario", str(s), "--config", str(c), *quick])
        for s, c in zip(scenarios, [*configs, *[configs[-1]] * len(scenarios)], strict=False)
    ]
    runs += [(f"config {c.name}", ["--config", str(c), *quick]) for c in configs[len(scenarios) :]]
    runs += [
        (f"route {p.name}", ["--route", str(p), "--perception", "radar", *quick])
        for p in sorted(EXAMPLES.glob("routes/*.toml"))
    ]
    return runs


@pytest.mark.parametrize(("name", "args"), _example_runs(), ids=[n for n, _ in _example_runs()])
def test_every_example_file_runs(name: str, args: list[str], tmp_path: Path) -> None:
    scenario = next((Path(b) for a, b in itertools.pairwise(args) if a == "--scenario"), None)
    if scenario is not None and lastmile.load_scenario(scenario).snow_cover_lane_m > 0:
        args = [*args, "--perception", "lidar"]  # snow cover is seen by the raw LiDARs only
    result = CliRunner().invoke(app, ["run", *args, "--no-black-box", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "run" / "metrics.json").exists()


MAPPING_EXAMPLES = sorted(EXAMPLES.glob("mapping/*.toml"))
"""Configurations that need a map the user builds first (``lastmile map build``): on a fresh clone
they are refused in one line, which the test below checks."""


@pytest.mark.parametrize("config", MAPPING_EXAMPLES, ids=[p.name for p in MAPPING_EXAMPLES])
def test_a_mapping_example_before_its_map_is_built_is_one_clear_line(
    config: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # a fresh clone's working directory: no map built yet
    out = str(tmp_path / "run")
    result = CliRunner().invoke(app, ["run", "--config", str(config), "--minutes", "0.01", "--out", out])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code != 0
    assert len(lines) == 1 and "map" in lines[0] and "no such file" in lines[0], result.output


def test_every_example_file_is_in_a_run() -> None:
    named = {Path(a).name for _, args in _example_runs() for a in args if a.endswith(".toml")}
    named |= {p.name for p in MAPPING_EXAMPLES}  # each refused in one line above
    assert named == {p.name for p in EXAMPLES.glob("*/*.toml")}
    assert {"scenarios", "configs", "routes"} <= {p.parent.name for p in EXAMPLES.glob("*/*.toml")}


def test_the_python_api_runs_and_returns_metrics_without_writing_to_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    scenario = lastmile.load_scenario(EXAMPLES / "scenarios" / "snow_cover.toml")
    scenario = dataclasses.replace(scenario, snow_cover_lane_m=0.0)  # radar perception: no snow bank
    result = lastmile.run(scenario, lastmile.RunConfig(), minutes=0.05, weather="clear", perception="radar")
    assert result.log.meta.scenario_name == "snow_cover" and result.log.meta.weather == "clear"
    assert result.metrics["duration_s"] == pytest.approx(3.0, abs=0.03)
    assert result.metrics == lastmile.evaluate(result.log)
    assert not any(tmp_path.iterdir())
    lastmile.evaluate(result.log, out=tmp_path / "run")
    assert (tmp_path / "run" / "report.md").exists()


def test_the_python_api_refuses_bad_input_with_the_clis_message() -> None:
    with pytest.raises(lastmile.api.ConfigError, match=r"perception: expected one of \['lidar', 'radar'\]"):
        lastmile.run(minutes=0.05, perception="oracle")


def test_importing_a_subpackage_does_not_load_the_simulator() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    code = (
        "import sys, lastmile.core.stamp; print('lastmile.sim' in sys.modules, 'lastmile.api' in sys.modules)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert proc.stdout.split() == ["False", "False"]


def test_lanelet2_is_required_on_every_platform_so_pip_stops_at_install_where_no_wheel_exists() -> None:
    from packaging.requirements import Requirement

    deps = [
        Requirement(d)
        for d in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    ]
    lanelet2 = next(r for r in deps if r.name == "lanelet2")
    assert lanelet2.marker is None
