"""`lastmile map build` on recordings written by the recorder itself (a synthetic scene, fast).

The scene is the wall corner, boxes and poles of ``tests/localization/lidar_scene.py``; the vehicle
drives past it while one LiDAR sweeps it, and ``/localization/estimate`` (hence ``/tf``) carries the
pose the vehicle believed. The map's points must lie on the scene's surfaces; with the recorded poses
off by a few centimetres, registration to the frames already placed must make the map sharper than
placing the frames as recorded. Bad inputs are one line and exit 1.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.geometry import SE2
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.localization.map_build import MapBuildConfig
from lastmile.localization.occupancy_map import read_grid
from lastmile.localization.point_cloud_map import read_point_cloud_map, sidecar_path
from lastmile.recorder.foxglove_views import ViewBuilder, planar_matrix
from lastmile.recorder.mcap_dump import write_mcap
from lastmile.runner.map_build_replay import build_map
from tests.localization.lidar_scene import pose, surfaces, sweep

MOUNT = pose((1.0, 0.0, 1.9), (0.0, 0.0, 0.0))
SPEED_MPS = 2.0
FRAME_US = 100_000
FRAMES = 12


def _truth(t_us: int) -> SE2:
    return SE2(-4.0 + SPEED_MPS * t_us / 1e6, -1.0, 0.05)


def _write(
    path: Path,
    *,
    clouds: bool = True,
    poses: bool = True,
    pose_noise_m: float = 0.0,
    source: PositionSource = PositionSource.GNSS,
) -> Path:
    rng = np.random.default_rng(3)
    entries: list[tuple[int, str, object]] = []
    for k in range(FRAMES):
        t_us = k * FRAME_US
        true = _truth(t_us)
        if poses:
            dx, dy = rng.normal(0.0, pose_noise_m, 2) if pose_noise_m else (0.0, 0.0)
            est = LocalizationEstimate(
                stamp=Stamp(t_us),
                map_from_base=SE2(true.x_m + dx, true.y_m + dy, true.yaw_rad),
                speed_mps=SPEED_MPS,
                yaw_rate_radps=0.0,
                pos_std_m=max(pose_noise_m, 0.02),  # the noise it carries, as an honest filter says
                yaw_std_rad=0.002,
                valid=True,
                source=source,
            )
            entries.append((t_us, "/localization/estimate", est))
        if clouds:
            xyz = sweep(rng, planar_matrix(true.x_m, true.y_m, true.yaw_rad) @ MOUNT, density=20.0)
            points = np.zeros((len(xyz), 6), dtype=np.float32)
            points[:, :3] = xyz
            entries.append(
                (
                    t_us,
                    "/sensors/lidar/front",
                    LidarSweep(stamp=Stamp(t_us), sensor_id="front", points=points),
                )
            )
    write_mcap(path, entries, views=ViewBuilder(sensor_mounts={"lidar_front": MOUNT}))
    return path


def _surface_distance_m(points: np.ndarray) -> np.ndarray:
    scene = surfaces(np.random.default_rng(0), density=2000.0)
    return cKDTree(scene).query(points)[0]


def test_writes_a_pcd_on_the_scene_and_its_sidecar(tmp_path: Path) -> None:
    rec = _write(tmp_path / "drive.mcap")
    out = tmp_path / "maps" / "campus.pcd"
    result = CliRunner().invoke(app, ["map", "build", str(rec), "--out", str(out), "--voxel", "0.1"])
    assert result.exit_code == 0, result.output
    assert f"wrote {out}" in result.output
    points = read_point_cloud_map(out)
    side = json.loads(sidecar_path(out).read_text())
    assert side["frame"] == "map" and side["voxel_m"] == 0.1 and side["points"] == len(points)
    assert side["frames_total"] == FRAMES and 1 < side["frames_used"] < FRAMES  # keyframes: 1 m of travel
    assert side["source"] == str(rec)
    assert side["occupancy_map"] == "campus.yaml"
    grid = read_grid(out.with_suffix(".yaml"))  # the amcl mode's map: the scene's walls and poles
    assert np.asarray(grid.occupied).any() and grid.resolution_m == 0.1
    np.testing.assert_allclose(side["extent_min_m"], points.min(axis=0), atol=1e-9)
    # On the scene's surfaces (2 cm range noise, 0.1 m voxels): not a cloud in the sensor's frame.
    assert np.percentile(_surface_distance_m(points), 95) < 0.05


def test_registration_sharpens_a_map_from_noisy_recorded_poses(tmp_path: Path) -> None:
    rec = _write(tmp_path / "noisy.mcap", pose_noise_m=0.05)
    every = MapBuildConfig(voxel_m=0.05, keyframe_m=0.1)
    registered = build_map(rec, tmp_path / "reg.pcd", every)
    as_recorded = build_map(
        rec, tmp_path / "raw.pcd", MapBuildConfig(voxel_m=0.05, keyframe_m=0.1, register=False)
    )
    assert registered.info.frames_registered >= FRAMES - 2
    assert as_recorded.info.frames_registered == 0
    assert registered.info.correction_max_m is not None and registered.info.correction_max_m < 0.3
    sharp = np.percentile(_surface_distance_m(read_point_cloud_map(tmp_path / "reg.pcd")), 90)
    blurred = np.percentile(_surface_distance_m(read_point_cloud_map(tmp_path / "raw.pcd")), 90)
    assert sharp < 0.8 * blurred, (sharp, blurred)


def _one_line_exit_1(args: list[str], expected: str) -> None:
    result = CliRunner().invoke(app, ["map", "build", *args])
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lastmile map build: "), result.output
    assert expected in lines[0], lines[0]
    assert "Traceback" not in result.output


def test_a_recording_without_clouds_is_one_line(tmp_path: Path) -> None:
    rec = _write(tmp_path / "no_clouds.mcap", clouds=False)
    _one_line_exit_1([str(rec), "--out", str(tmp_path / "m.pcd")], "expected LiDAR point clouds")
    assert not (tmp_path / "m.pcd").exists()


def test_a_recording_without_poses_is_one_line(tmp_path: Path) -> None:
    rec = _write(tmp_path / "no_poses.mcap", poses=False)
    _one_line_exit_1([str(rec), "--out", str(tmp_path / "m.pcd")], "expected the vehicle's poses")


def test_a_recording_on_dead_reckoning_places_no_frame(tmp_path: Path) -> None:
    rec = _write(tmp_path / "dr.mcap", source=PositionSource.DEAD_RECKONING)
    _one_line_exit_1([str(rec), "--out", str(tmp_path / "m.pcd")], "without an absolute pose")


def test_bad_arguments_are_one_line(tmp_path: Path) -> None:
    out = ["--out", str(tmp_path / "m.pcd")]
    _one_line_exit_1([str(tmp_path / "missing.mcap"), *out], "missing.mcap")
    rec = _write(tmp_path / "ok.mcap")
    _one_line_exit_1(
        [str(rec), "--voxel", "0", *out], "--voxel: expected a voxel size in [0.01, 5] m, got 0.0"
    )
    bad = tmp_path / "not.mcap"
    bad.write_text("not an mcap file\n")
    _one_line_exit_1([str(bad), *out], str(bad))


def test_record_map_needs_the_raw_lidar(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        [
            "run",
            "--perception",
            "radar",
            "--minutes",
            "0.01",
            "--out",
            str(tmp_path / "run"),
            "--record-map",
            str(tmp_path / "d.mcap"),
        ],
    )
    assert result.exit_code == 2, result.output
    assert result.output.strip() == (
        "lastmile run: --record-map: expected raw LiDAR perception, got 'radar_tracking' (no sweeps)"
    )
