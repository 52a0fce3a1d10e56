"""``lastmile replay`` reads what ``lastmile perceive`` writes (Foxglove protobuf, no black-box profile)."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.config import from_mapping
from lastmile.perception.perceive import PerceiveConfig, perceive_files
from lastmile.recorder.replay import read_recording
from lastmile.recorder.replay_render import render_png
from tests.perception import cloud_fixtures as fx


def _perceive_mcap(tmp_path: Path) -> Path:
    scan = fx.spinning_scan()
    config = from_mapping(
        PerceiveConfig,
        {"sensor": {"sensor_id": "top", "model": {"name": "vlp16", "azimuth_resolution_deg": 2.0},
                    "mount": {"z_m": fx.SENSOR_HEIGHT_M}},
         "pipeline": {"crop": {"ego_x_min_m": -0.5, "ego_x_max_m": 0.5, "ego_half_width_m": 0.5}}},
        "test",
    )  # fmt: skip
    out = tmp_path / "out"
    perceive_files([fx.write_kitti_bin(tmp_path / "000001.bin", scan)], config, out)
    return out / "objects.mcap"


def test_replay_reads_and_draws_a_perceive_recording(tmp_path: Path) -> None:
    path = _perceive_mcap(tmp_path)
    rec = read_recording(path)
    assert rec.warning is None and rec.messages == ()  # no lossless stack records: views only
    assert {(c.topic, c.schema) for c in rec.channels} == {
        ("/lidar/points", "foxglove.PointCloud"),
        ("/perception/objects", "foxglove.SceneUpdate"),
    }
    assert {v.schema for v in rec.views} == {"foxglove.PointCloud", "foxglove.SceneUpdate"}
    shot = render_png(rec, tmp_path / "frame.png")
    # No transform tree: the data's own frame is the fixed frame; the box perceive found is drawn.
    assert shot.fixed_frame == "base" and shot.cloud_points > 1000 and shot.boxes >= 1, shot
    result = CliRunner().invoke(app, ["replay", str(path)])
    assert result.exit_code == 0 and "/perception/objects" in result.output, result.output
