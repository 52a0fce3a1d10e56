"""A learned LiDAR detector selected in the run configuration: its boxes reach the published tracks.

The detector is the tests' tiny BEV peak model (built here with onnx's helper API, nothing downloaded):
it calls every peak of the non-ground points' height map above 0.3 m within 4 m of the lane a
cyclist, with a 1.6 m square footprint (its 0.5 m cells place a box up to 0.35 m off the object's
centre; that footprint covers the 0.8 m box wherever its cell puts it). A box stands on the lane
20 m ahead; the simulator's camera calls it unknown at best, so a cyclist track there can only come
from the model, through late fusion and aUToTrack.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.perception.bev_raster import BevChannel, BevGrid
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.run_config import load_run_config
from lastmile.sim.scenario import Scenario, StaticObstacle
from lastmile.stack.shuttle_stack import ShuttleStack
from tests.perception.tiny_onnx import bev_peak_detector

pytestmark = pytest.mark.closed_loop

SECONDS = 2.0


def _config_file(tmp_path: Path, model: Path, perception: str = "lidar_camera_radar") -> Path:
    path = tmp_path / "run.toml"
    path.write_text(
        f"""
[stack]
perception = "{perception}"

[stack.lidar_detector]
model = "{model}"
points = "non_ground"

[stack.lidar_detector.grid]
x_min_m = 0.0
x_max_m = 40.0
y_min_m = -4.0
y_max_m = 4.0
z_min_m = 0.0
z_max_m = 3.0
cell_m = 0.5
channels = ["max_height"]
"""
    )
    return path


def test_the_detectors_boxes_replace_the_cluster_and_reach_the_published_tracks(tmp_path: Path) -> None:
    grid = BevGrid(
        x_min_m=0.0, x_max_m=40.0, y_min_m=-4.0, y_max_m=4.0, z_min_m=0.0, z_max_m=3.0, cell_m=0.5,
        channels=(BevChannel.MAX_HEIGHT,),
    )  # fmt: skip
    model = bev_peak_detector(
        tmp_path / "peaks.onnx",
        grid,
        threshold=0.3,
        class_id=int(ObjectClass.CYCLIST),
        box_lwh_m=(1.6, 1.6, 1.0),
    )
    config = load_run_config(_config_file(tmp_path, model))
    assert config.stack.lidar_detector is not None and config.stack.lidar_detector.grid == grid
    scenario = Scenario(
        name="box_ahead", minutes=SECONDS / 60.0, static_obstacles=(StaticObstacle(route_s_m=20.0),)
    )
    loop = build_closed_loop(scenario, config)
    stack = loop.software
    assert isinstance(stack, ShuttleStack) and stack.raw is not None and stack.raw.detector is not None
    box = loop.world.road_users[-1]
    seen = []
    for record in loop.ticks(round(SECONDS * 1e6 / loop.tick_us)):
        out = record.output
        assert out is not None, record.failure
        if out.decision is None or record.tick < 100:
            continue
        t = stack._tracks.table
        near = np.hypot(t[:, 0] - box.x_m, t[:, 1] - box.y_m)
        # One track at the box (no unclassified twin from its cluster), and it is the model's cyclist.
        assert (near < 1.5).sum() == 1, t[near < 1.5]
        i = int(np.argmin(near))
        assert near[i] < 0.6 and int(t[i, 7]) == int(ObjectClass.CYCLIST)
        seen.append(record.tick)
    assert len(seen) >= 8
    report = stack.report().perception
    assert report["detections_per_frame"] is not None and report["detections_per_frame"] >= 0.9
    assert report["clusters_replaced_per_frame"] is not None and report["clusters_replaced_per_frame"] >= 0.9


def test_a_detector_without_the_raw_sensors_or_with_a_bad_model_is_refused_before_the_run(
    tmp_path: Path,
) -> None:
    model = tmp_path / "peaks.onnx"
    with pytest.raises(ConfigError, match=r"lidar_detector: expected perception = 'lidar_camera_radar'"):
        load_run_config(_config_file(tmp_path, model, perception="radar_tracking"))
    # The file is missing: refused when the vehicle is built, before the first tick.
    config = load_run_config(_config_file(tmp_path, model))
    with pytest.raises(ConfigError, match="expected an ONNX model file, got no such file"):
        build_closed_loop(Scenario(name="unit", minutes=0.05), config)
    bad = _config_file(tmp_path, model).read_text().replace('"max_height"', '"height"')
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(ConfigError, match=r"stack\.lidar_detector\.grid\.channels\[0\]"):
        load_run_config(tmp_path / "bad.toml")
