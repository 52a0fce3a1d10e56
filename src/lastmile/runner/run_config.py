"""The run configuration: the vehicle software (which modules, their parameters) and the loop.

A scenario is the world; a run configuration is everything on the vehicle's side. Both are TOML files,
frozen and checked: unknown keys, unknown module names and combinations the scenario cannot serve are
rejected with one line before any work starts.

Example (every key optional)::

    [stack]
    perception = "radar_tracking"      # or "lidar_camera_radar" (the default)
    lateral_controller = "pure_pursuit"
    cruise_speed_mps = 3.33
    lidar_mounts = "calib.toml"        # `lastmile calibrate lidar --out`; read beside this file first
    camera_mounts = "cameras.toml"     # `lastmile calibrate camera --out`; likewise

    [stack.safety]
    max_decel_mps2 = 5.0

    [loop]
    tick_us = 10000
    black_box = true
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from lastmile.core.config import check_range, from_mapping, load_toml, resolve_file
from lastmile.core.errors import ConfigError
from lastmile.core.perception_mode import PerceptionMode
from lastmile.sim.faults import RAW_SENSOR_TARGET_PREFIXES
from lastmile.sim.scenario import Scenario
from lastmile.stack.stack_settings import StackSettings

BASE_TICK_US = 10_000
"""DESIGN.md's base period; the loop's tick must divide it (module rates are multiples of 10 ms)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopSettings:
    """The loop's side of a run.

    Attributes:
        tick_us: the base tick, a divisor of 10 ms (module periods are whole numbers of ticks).
        black_box: keep the rolling black box and write it on a takeover, collision, e-stop or crash.
        black_box_window_s: how much the black box keeps (WATonoBus: 30 s).
    """

    tick_us: int = BASE_TICK_US
    black_box: bool = True
    black_box_window_s: float = 30.0

    def __post_init__(self) -> None:
        if self.tick_us <= 0 or BASE_TICK_US % self.tick_us != 0:
            raise ConfigError(f"loop.tick_us: expected a divisor of {BASE_TICK_US} µs, got {self.tick_us}")
        check_range("loop.black_box_window_s", self.black_box_window_s, 1.0, 600.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class RunConfig:
    """The vehicle software and the loop of a run (the scenario is the world)."""

    stack: StackSettings = field(default_factory=StackSettings)
    loop: LoopSettings = field(default_factory=LoopSettings)

    def with_perception(self, mode: PerceptionMode) -> RunConfig:
        return dataclasses.replace(self, stack=dataclasses.replace(self.stack, perception=mode))

    def with_cruise_speed(self, speed_mps: float | None) -> RunConfig:
        return dataclasses.replace(self, stack=dataclasses.replace(self.stack, cruise_speed_mps=speed_mps))

    def check_serves(self, scenario: Scenario) -> None:
        """Raise a :class:`ConfigError` if this configuration cannot run ``scenario`` as written."""
        if self.stack.perception.needs_raw_sensors:
            return
        if scenario.snow_cover_lane_m > 0.0:
            raise ConfigError(
                f"run configuration: perception '{self.stack.perception}' cannot serve scenario "
                f"{scenario.name!r}: its snow_cover_lane_m ({scenario.snow_cover_lane_m} m) is seen only by "
                f"the raw LiDARs; expected perception = '{PerceptionMode.LIDAR_CAMERA_RADAR}'"
            )
        raw_faults = [f for f in scenario.faults if f.target.startswith(RAW_SENSOR_TARGET_PREFIXES)]
        if raw_faults:
            f = raw_faults[0]
            raise ConfigError(
                f"run configuration: perception '{self.stack.perception}' cannot serve scenario "
                f"{scenario.name!r}: its fault {f.kind}:{f.target} targets a sensor that mode does not read; "
                f"expected perception = '{PerceptionMode.LIDAR_CAMERA_RADAR}'"
            )


FILE_KEYS = (
    ("stack", "lidar_mounts"),
    ("stack", "camera_mounts"),
    ("stack", "scan_matching", "map"),
    ("stack", "amcl", "map"),
    ("stack", "lidar_detector", "model"),
)
"""Keys naming files; read beside the configuration file first, then from the working directory."""


def load_run_config(path: Path) -> RunConfig:
    """Read and check a run configuration TOML file (the files it names: :data:`FILE_KEYS`)."""
    data = load_toml(path)
    for keys in FILE_KEYS:
        _resolve_file_key(data, keys, path)
    return from_mapping(RunConfig, data, str(path))


def _resolve_file_key(data: dict[str, Any], keys: tuple[str, ...], source: Path) -> None:
    table: Any = data
    for key in keys[:-1]:
        table = table.get(key) if isinstance(table, dict) else None
    if not isinstance(table, dict):
        return
    given = table.get(keys[-1])
    if isinstance(given, str) and given:
        # Not found anywhere: left as written, for the module's own one-line message.
        found = resolve_file(source, given)
        table[keys[-1]] = str(found) if found is not None else given


def run_config_dict(config: RunConfig) -> dict[str, Any]:
    """JSON- and TOML-able echo of ``config`` (enums as their values, no None)."""
    return _plain(dataclasses.asdict(config))


def run_config_to_toml(config: RunConfig) -> str:
    """The configuration as a TOML file that :func:`load_run_config` reads back to an equal one."""
    return tomli_w.dumps(run_config_dict(config))


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items() if v is not None}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, enum.Enum):
        return value.value
    return value
