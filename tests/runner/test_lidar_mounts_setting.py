"""`[stack] lidar_mounts`: the stack runs on a calibration file's LiDAR mounts, not the simulator's true
ones (issue 19: "the stack can then run on calibrated mounts"), and the run records the mounts it used."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomli_w

from lastmile.core.errors import ConfigError
from lastmile.localization.lidar_mount_file import mount_row
from lastmile.runner.closed_loop import build_closed_loop, sensor_calibration
from lastmile.runner.run_config import load_run_config
from lastmile.sim.scenario import Scenario
from lastmile.stack.shuttle_stack import ShuttleStack
from tests.localization.lidar_scene import perturbed

SCENARIO = Scenario(name="mounts", minutes=0.01)


def _mounts_file(path: Path, mounts: dict[str, np.ndarray]) -> Path:
    path.write_text(tomli_w.dumps({"lidar_mount": [mount_row(k, v) for k, v in mounts.items()]}))
    return path


def _config(folder: Path, mounts_name: str, perception: str = "lidar_camera_radar") -> Path:
    path = folder / "run.toml"
    path.write_text(f'[stack]\nperception = "{perception}"\nlidar_mounts = "{mounts_name}"\n')
    return path


def test_the_stack_runs_on_the_files_mounts(tmp_path: Path) -> None:
    true = {
        s.sensor_id: s.base_from_sensor for s in build_closed_loop(SCENARIO).world.raw_sensors.lidar_specs
    }
    calibrated = {k: perturbed(v, 0.2, 2.0) if k == "left" else v for k, v in true.items()}
    _mounts_file(tmp_path / "mounts.toml", calibrated)
    # Named relative to the configuration file, read from any working directory.
    config = load_run_config(_config(tmp_path, "mounts.toml"))
    loop = build_closed_loop(SCENARIO, config)
    stack = loop.software
    assert isinstance(stack, ShuttleStack) and stack.raw is not None
    used = stack.raw.lidar_mounts
    for sensor_id, mount in calibrated.items():
        np.testing.assert_allclose(used[sensor_id], mount, atol=2e-5)
    assert np.abs(used["left"][:3, 3] - true["left"][:3, 3]).max() > 0.05  # not the simulator's
    # The simulator's sensors stay where they are; what the run records is the vehicle's calibration.
    spec = {s.sensor_id: s for s in loop.world.raw_sensors.lidar_specs}["left"]
    np.testing.assert_array_equal(spec.base_from_sensor, true["left"])
    recorded = sensor_calibration(loop.world, config.stack).lidar_mounts["left"]
    np.testing.assert_allclose(recorded, calibrated["left"], atol=2e-5)


def test_a_file_without_every_lidar_is_one_line(tmp_path: Path) -> None:
    _mounts_file(tmp_path / "mounts.toml", {"front": np.eye(4)})
    config = load_run_config(_config(tmp_path, "mounts.toml"))
    with pytest.raises(
        ConfigError, match=r"expected a mount for each of the vehicle's LiDARs .* \(missing \["
    ):
        build_closed_loop(SCENARIO, config)


def test_bad_settings_are_one_line_before_the_run(tmp_path: Path) -> None:
    with pytest.raises(
        ConfigError, match=r"stack.lidar_mounts: .*nope.toml: expected a TOML file, got no such"
    ):
        load_run_config(_config(tmp_path, "nope.toml"))
    _mounts_file(tmp_path / "mounts.toml", {"front": np.eye(4)})
    with pytest.raises(ConfigError, match=r"stack.lidar_mounts: expected perception = 'lidar_camera_radar'"):
        load_run_config(_config(tmp_path, "mounts.toml", perception="radar_tracking"))
