"""The Python API: the CLI's ``run`` and its inputs as functions, returning results instead of files.

    >>> import lastmile
    >>> result = lastmile.run(minutes=0.5, perception="radar")
    >>> result.metrics["collisions_total"]
    0

Nothing is written to disk unless asked: ``run(..., black_box_dir=...)`` keeps incident recordings,
``evaluate(log, out=...)`` writes the run directory the CLI writes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lastmile.core.errors import ConfigError
from lastmile.core.perception_mode import PerceptionMode
from lastmile.evaluation.metrics import MetricValue, compute_metrics
from lastmile.recorder.run_log import RunLog
from lastmile.runner import closed_loop
from lastmile.runner.run_config import RunConfig, load_run_config
from lastmile.sim.scenario import MapSpec, Scenario, default_service, load_scenario, route_service
from lastmile.sim.weather import parse_weather

PERCEPTION_NAMES = {"lidar": PerceptionMode.LIDAR_CAMERA_RADAR, "radar": PerceptionMode.RADAR_TRACKING}
"""The CLI's ``--perception`` values."""

__all__ = ["RunConfig", "RunResult", "Scenario", "evaluate", "load_run_config", "load_scenario", "run"]


@dataclass(frozen=True, slots=True, kw_only=True)
class RunResult:
    """One closed-loop run: its log (signals, events, timing) and its metrics."""

    log: RunLog
    metrics: dict[str, MetricValue]

    @property
    def interrupted(self) -> bool:
        """Whether Ctrl-C (or ``stop``) ended the run before its scenario's end."""
        return bool(self.log.timing.get("interrupted"))


def run(
    scenario: Scenario | str | Path | None = None,
    config: RunConfig | str | Path | None = None,
    *,
    minutes: float | None = None,
    seed: int | None = None,
    weather: str | None = None,
    perception: str | None = None,
    route: str | Path | None = None,
    black_box_dir: Path | None = None,
    stop: Callable[[], bool] | None = None,
) -> RunResult:
    """Simulate a scenario in closed loop, as ``lastmile run`` does, without writing a run directory.

    Args:
        scenario: a :class:`Scenario`, a scenario TOML file, or None for the campus service (or the
            service of ``route``).
        config: a :class:`RunConfig`, a run configuration TOML file, or None for the default.
        minutes, seed, weather: override the scenario's (``--minutes``, ``--seed``, ``--weather``).
        perception: "lidar" or "radar" (``--perception``); None keeps the configuration's.
        route: a route file (``--route``): its map and stops instead of the campus.
        black_box_dir: where incident recordings go (None: the black box writes nothing).
        stop: polled between ticks; True ends the run early with what was done.

    Raises:
        LastmileError: a bad input, naming what was expected and what arrived, before the run starts.
    """
    spec, run_config = prepare_run(
        scenario, config, minutes=minutes, seed=seed, weather=weather, perception=perception, route=route
    )
    # Looked up when called, not bound at import: the API runs what the runner module holds now.
    log = closed_loop.run_scenario(spec, run_config, black_box_dir=black_box_dir, stop=stop)
    return RunResult(log=log, metrics=compute_metrics(log))


def prepare_run(
    scenario: Scenario | str | Path | None = None,
    config: RunConfig | str | Path | None = None,
    *,
    minutes: float | None = None,
    seed: int | None = None,
    weather: str | None = None,
    perception: str | None = None,
    route: str | Path | None = None,
) -> tuple[Scenario, RunConfig]:
    """The scenario and run configuration :func:`run` (and ``lastmile run``) would simulate, with the
    overrides applied and checked against each other before any work starts (arguments as :func:`run`).

    Raises:
        LastmileError: a bad input, naming what was expected and what arrived.
    """
    spec = _scenario(scenario, route)
    overrides: dict[str, Any] = {}
    if minutes is not None:
        overrides["minutes"] = minutes
    if seed is not None:
        overrides["seed"] = seed
    if weather is not None:
        parse_weather(weather)
        overrides["weather"] = weather
    spec = dataclasses.replace(spec, **overrides)
    run_config = _config(config, perception)
    run_config.check_serves(spec)
    return spec, run_config


def evaluate(log: RunLog, out: Path | None = None) -> dict[str, MetricValue]:
    """The metrics of a run log; with ``out``, also the run directory ``lastmile run`` writes there
    (run log, metrics.json, timing.json, report.md with plots)."""
    if out is None:
        return compute_metrics(log)
    config = log.meta.config.get("map", {})
    spec = MapSpec(**config) if isinstance(config, dict) else MapSpec()
    return closed_loop.evaluate_run(log, out, hdmap=closed_loop.load_world_map(spec).hdmap)


def _scenario(scenario: Scenario | str | Path | None, route: str | Path | None) -> Scenario:
    if isinstance(scenario, Scenario):
        spec = scenario
    elif scenario is not None:
        spec = load_scenario(Path(scenario))
    else:
        return route_service(str(route)) if route is not None else default_service()
    if route is not None:
        spec = dataclasses.replace(spec, map=MapSpec(name="route", route=str(route)))
    return spec


def _config(config: RunConfig | str | Path | None, perception: str | None) -> RunConfig:
    base = config if isinstance(config, RunConfig) else RunConfig() if config is None else None
    if base is None:
        base = load_run_config(Path(str(config)))
    if perception is None:
        return base
    if perception not in PERCEPTION_NAMES:
        raise ConfigError(f"perception: expected one of {sorted(PERCEPTION_NAMES)}, got {perception!r}")
    return base.with_perception(PERCEPTION_NAMES[perception])
