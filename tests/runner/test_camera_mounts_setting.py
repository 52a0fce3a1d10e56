"""`[stack] camera_mounts`: the stack runs on a calibration file's camera mounts, not the simulator's true
ones (issue 19: "the stack can then run on calibrated mounts"), for raw perception's cameras and the
traffic-light cameras; the file must name the vehicle's cameras exactly."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.vehicle import VehicleGeometry
from lastmile.localization.camera_mount_file import (
    CameraMountRow,
    MountPose,
    body_pose,
    camera_from_parent,
    write_camera_mounts,
)
from lastmile.runner.closed_loop import build_closed_loop, sensor_calibration
from lastmile.runner.run_config import load_run_config
from lastmile.sim.camera import default_cameras
from lastmile.sim.scenario import Scenario
from lastmile.stack.shuttle_stack import ShuttleStack

SCENARIO = Scenario(name="camera mounts", minutes=0.01)


def _row(camera_id: str, pose: MountPose) -> CameraMountRow:
    return CameraMountRow(
        camera_id=camera_id, x_m=pose.x_m, y_m=pose.y_m, z_m=pose.z_m, roll_rad=pose.roll_rad,
        pitch_rad=pose.pitch_rad, yaw_rad=pose.yaw_rad, source="calibrated",
    )  # fmt: skip


def _config(folder: Path, mounts_name: str, perception: str = "lidar_camera_radar") -> Path:
    path = folder / "run.toml"
    path.write_text(f'[stack]\nperception = "{perception}"\ncamera_mounts = "{mounts_name}"\n')
    return path


def _true_poses() -> dict[str, MountPose]:
    """The simulator's cameras (the vehicle's, whichever perception runs)."""
    return {c.camera_id: body_pose(c.camera_from_base) for c in default_cameras(VehicleGeometry())}


@pytest.mark.parametrize("perception", ["lidar_camera_radar", "radar_tracking"])
def test_the_stack_runs_on_the_files_camera_mounts(tmp_path: Path, perception: str) -> None:
    true = _true_poses()
    assert sorted(true) == ["front", "rear"]
    front = true["front"]
    moved = MountPose(
        x_m=front.x_m + 0.1, y_m=front.y_m - 0.05, z_m=front.z_m, roll_rad=front.roll_rad + math.radians(1.0),
        pitch_rad=front.pitch_rad, yaw_rad=front.yaw_rad - math.radians(2.0),
    )  # fmt: skip
    folder = tmp_path / "vehicle"
    folder.mkdir()
    write_camera_mounts(folder / "cameras.toml", [_row("front", moved), _row("rear", true["rear"])])
    # Named relative to the configuration file, read from any working directory.
    config = load_run_config(_config(folder, "cameras.toml", perception))
    loop = build_closed_loop(SCENARIO, config)
    stack = loop.software
    assert isinstance(stack, ShuttleStack)
    expected = camera_from_parent(moved)
    light = {c.camera_id: c for c in stack.config.light_cameras}
    np.testing.assert_allclose(light["front"].camera_from_base, expected, atol=1e-5)
    if perception == "lidar_camera_radar":
        assert stack.raw is not None
        fused = {c.camera_id: c for c in stack.raw.cameras}
        np.testing.assert_allclose(fused["front"].camera_from_base, expected, atol=1e-5)
        np.testing.assert_allclose(
            fused["rear"].camera_from_base, camera_from_parent(true["rear"]), atol=1e-5
        )
        assert fused["front"].x_m == pytest.approx(front.x_m + 0.1, abs=1e-5)  # optical centre derived anew
        # The simulator's cameras stay where they are; the run records the vehicle's calibration.
        assert loop.world.raw_sensors is not None
        sim_front = {c.camera.camera_id: c.camera for c in loop.world.raw_sensors.cameras}["front"]
        np.testing.assert_allclose(sim_front.camera_from_base, camera_from_parent(front), atol=1e-9)
    recorded = {c.camera_id: c for c in sensor_calibration(loop.world, config.stack).light_cameras}
    np.testing.assert_allclose(recorded["front"].camera_from_base, expected, atol=1e-5)


def test_a_file_without_every_camera_is_one_line(tmp_path: Path) -> None:
    write_camera_mounts(tmp_path / "cameras.toml", [_row("front", MountPose(x_m=3.0, y_m=0.0, z_m=2.2))])
    config = load_run_config(_config(tmp_path, "cameras.toml"))
    with pytest.raises(
        ConfigError,
        match=r"stack.camera_mounts: .*a mount for each camera \['front', 'rear'\], got missing \['rear'\]",
    ):
        build_closed_loop(SCENARIO, config)


def test_a_camera_the_vehicle_does_not_have_is_one_line(tmp_path: Path) -> None:
    pose = MountPose(x_m=3.0, y_m=0.0, z_m=2.2)
    write_camera_mounts(tmp_path / "c.toml", [_row(k, pose) for k in ("front", "rear", "left")])
    config = load_run_config(_config(tmp_path, "c.toml", "radar_tracking"))
    with pytest.raises(ConfigError, match=r"got not on this vehicle \['left'\]"):
        build_closed_loop(SCENARIO, config)


def test_bad_files_are_one_line_before_the_run(tmp_path: Path) -> None:
    with pytest.raises(
        ConfigError, match=r"stack.camera_mounts: .*nope.toml: expected a TOML file, got no such"
    ):
        load_run_config(_config(tmp_path, "nope.toml"))
    (tmp_path / "bad.toml").write_text('[[camera_mount]]\ncamera_id = "front"\nx_m = 1.0\n')
    with pytest.raises(
        ConfigError, match=r"stack.camera_mounts: .*camera_mount\[0\]: missing required key 'y_m'"
    ):
        load_run_config(_config(tmp_path, "bad.toml"))
