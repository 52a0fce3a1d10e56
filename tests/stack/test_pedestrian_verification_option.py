"""``[stack.pedestrian_verification]``: NUS's verification of LiDAR pedestrian candidates by the camera
reaches the raw perception's late fusion (issue #20: selectable in the run configuration)."""

from __future__ import annotations

from pathlib import Path

import pytest

from lastmile.core.errors import ConfigError
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.run_config import load_run_config
from lastmile.sim.scenario import Scenario
from lastmile.stack.shuttle_stack import ShuttleStack


def test_the_table_turns_it_on_in_the_raw_chain(tmp_path: Path) -> None:
    path = tmp_path / "nus.toml"
    path.write_text("[stack.pedestrian_verification]\nmin_iou = 0.4\n")
    config = load_run_config(path)
    loop = build_closed_loop(Scenario(name="nus", minutes=0.01), config)
    stack = loop.software
    assert isinstance(stack, ShuttleStack) and stack.raw is not None
    verification = stack.raw.config.fusion.pedestrian_verification
    assert verification is not None and verification.min_iou == 0.4
    default = build_closed_loop(Scenario(name="default", minutes=0.01)).software
    assert isinstance(default, ShuttleStack) and default.raw is not None
    assert default.raw.config.fusion.pedestrian_verification is None


def test_it_needs_the_lidars(tmp_path: Path) -> None:
    path = tmp_path / "nus.toml"
    path.write_text('[stack]\nperception = "radar_tracking"\n[stack.pedestrian_verification]\n')
    with pytest.raises(
        ConfigError, match=r"stack.pedestrian_verification: expected perception = 'lidar_camera_radar'"
    ):
        load_run_config(path)
