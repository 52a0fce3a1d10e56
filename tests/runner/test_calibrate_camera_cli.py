"""`lastmile calibrate camera` on a folder of rendered board images and LiDAR clouds written by the test
(PNG + KITTI .bin, one PCD), the intrinsics as TOML and as a ROS camera_info YAML; bad inputs in one line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.errors import ConfigError
from lastmile.localization.camera_mount_file import (
    CameraMountRow,
    MountPose,
    camera_from_parent,
    read_camera_mounts,
    write_camera_mounts,
)
from lastmile.localization.lidar_calibration import mount_difference
from lastmile.runner.camera_calibration_files import read_intrinsics
from tests.localization.camera_lidar_session import INTRINSICS, TRUE_IN_LIDAR, TRUTH, perturbed, session

cv2 = pytest.importorskip("cv2", reason="the calibration extra (opencv-python-headless) is not installed")

LIDAR_IN_BASE = MountPose(x_m=1.5, y_m=0.0, z_m=2.0, yaw_rad=math.radians(1.0))
INTRINSICS_TOML = f"""fx = {INTRINSICS.fx_px}
fy = {INTRINSICS.fy_px}
cx = {INTRINSICS.cx_px}
cy = {INTRINSICS.cy_px}
width = {INTRINSICS.width_px}
height = {INTRINSICS.height_px}
"""


def _write_pcd(path: Path, xyz: np.ndarray) -> None:
    header = (
        "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {len(xyz)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(xyz)}\nDATA ascii\n"
    )
    path.write_text(header + "\n".join(f"{x:.5f} {y:.5f} {z:.5f}" for x, y, z in xyz) + "\n")


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("boards")
    for k, (image, cloud) in enumerate(session(seed=11, views=8, sweeps=1)):
        assert cv2.imwrite(str(out / f"view{k:02d}.png"), image)
        if k == 0:
            _write_pcd(out / f"view{k:02d}.pcd", cloud)
        else:
            rows = np.zeros((len(cloud), 4), dtype="<f4")
            rows[:, :3] = cloud
            (out / f"view{k:02d}.bin").write_bytes(rows.tobytes())
    (out.parent / "intrinsics.toml").write_text(INTRINSICS_TOML)
    return out


def _args(folder: Path, nominal: str, *extra: str) -> list[str]:
    return [
        "calibrate", "camera", str(folder), "--intrinsics", str(folder.parent / "intrinsics.toml"),
        "--board", "7x5", "--square", "0.1", "--nominal", nominal,
        "--lidar-mount", "1.5,0,2.0,0,0,1.0", *extra,
    ]  # fmt: skip


def _text(pose: MountPose) -> str:
    angles = (math.degrees(a) for a in (pose.roll_rad, pose.pitch_rad, pose.yaw_rad))
    return ",".join(f"{v:.9f}" for v in (pose.x_m, pose.y_m, pose.z_m, *angles))


def test_calibrates_the_camera_and_writes_its_mount_in_the_base_frame(folder, tmp_path):
    from lastmile.localization.camera_mount_file import body_pose

    nominal = body_pose(perturbed(TRUTH, np.random.default_rng(2)))
    out = tmp_path / "cameras.toml"
    rear = CameraMountRow(
        camera_id="rear", x_m=-0.5, y_m=0.0, z_m=2.2, roll_rad=0.0, pitch_rad=0.1, yaw_rad=3.1
    )
    write_camera_mounts(out, [rear])  # calibrated before: kept
    result = CliRunner().invoke(app, _args(folder, _text(nominal), "--camera-id", "front", "--out", str(out)))
    assert result.exit_code == 0, result.output
    assert "view07" in result.output and "camera in the LiDAR frame, after" in result.output
    assert "camera front in the base frame, after: (" in result.output
    mounts = read_camera_mounts(out)
    assert sorted(mounts) == ["front", "rear"]
    np.testing.assert_allclose(mounts["rear"], rear.camera_from_base(), atol=1e-6)
    # The written camera_from_base is the calibrated camera_from_lidar carried by the LiDAR's mount.
    truth_base = camera_from_parent(TRUE_IN_LIDAR) @ np.linalg.inv(LIDAR_IN_BASE.parent_from_child())
    pos_m, rot_rad = mount_difference(np.linalg.inv(truth_base), np.linalg.inv(mounts["front"]))
    # Eight single-sweep views (the unit test holds the 2 cm / 0.1 deg on twenty): the
    # perturbation of 20 cm / 2 deg must be mostly undone.
    assert pos_m < 0.03 and math.degrees(rot_rad) < 0.3, (pos_m, math.degrees(rot_rad))
    text = out.read_text()
    assert "[camera_mount.in_lidar]" in text and "[camera_mount.lidar_in_base]" in text


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (("--board", "7by5"), "--board: expected COLSxROWS inner corners such as 7x5, got '7by5'"),
        (
            ("--nominal", "0,0,0"),
            "--nominal: expected x,y,z,roll,pitch,yaw (m, m, m, deg, deg, deg), got '0,0,0'",
        ),
        (("--intrinsics", "missing.toml"), "missing.toml: expected a TOML file, got no such file"),
    ],
)
def test_bad_options_are_one_line(folder, change, expected):
    args = _args(folder, _text(TRUE_IN_LIDAR))
    i = args.index(change[0])
    args[i + 1] = change[1]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert expected in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_an_existing_output_that_is_no_mounts_file_is_refused_before_the_work(folder, tmp_path):
    out = tmp_path / "notes.toml"
    out.write_text('title = "not mounts"\n')
    result = CliRunner().invoke(app, _args(folder, _text(TRUE_IN_LIDAR), "--out", str(out)))
    assert result.exit_code == 2
    assert "notes.toml: unknown key 'title'; expected only [[camera_mount]] tables" in result.output
    assert out.read_text() == 'title = "not mounts"\n'


def test_an_image_without_its_cloud_is_one_line(folder, tmp_path):
    lonely = tmp_path / "lonely"
    lonely.mkdir()
    (lonely / "a.png").write_bytes((folder / "view01.png").read_bytes())
    (lonely.parent / "intrinsics.toml").write_text(INTRINSICS_TOML)
    result = CliRunner().invoke(app, _args(lonely, _text(TRUE_IN_LIDAR)))
    assert result.exit_code == 2
    assert (
        "expected each image paired with a cloud of the same name, got image(s) without a cloud: a"
        in result.output
    )


def test_too_few_views_with_a_board_is_one_line_naming_the_skipped(folder, tmp_path):
    few = tmp_path / "few"
    few.mkdir()
    for name in ("view01", "view02"):
        for suffix in (".png", ".bin"):
            (few / f"{name}{suffix}").write_bytes((folder / f"{name}{suffix}").read_bytes())
    blank = np.full((INTRINSICS.height_px, INTRINSICS.width_px), 128, dtype=np.uint8)
    cv2.imwrite(str(few / "blank.png"), blank)
    (few / "blank.bin").write_bytes((folder / "view03.bin").read_bytes())
    (few.parent / "intrinsics.toml").write_text(INTRINSICS_TOML)
    result = CliRunner().invoke(app, _args(few, _text(TRUE_IN_LIDAR)))
    assert result.exit_code == 2
    assert (
        "expected at least 3 views with the board found in both the image and the cloud, got 2"
        in result.output
    )
    assert "skipped blank: expected a 7x5 checkerboard" in result.output


def test_reads_a_ros_camera_info_yaml(tmp_path):
    path = tmp_path / "ost.yaml"
    path.write_text(
        "image_width: 2048\nimage_height: 1536\ncamera_name: front\n"
        "camera_matrix: {rows: 3, cols: 3, data: [1462.4, 0, 1024, 0, 1460.0, 768, 0, 0, 1]}\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.01, 0.001, 0.002, 0.0]}\n"
    )
    got = read_intrinsics(path)
    assert (got.fx_px, got.fy_px, got.cx_px, got.cy_px) == (1462.4, 1460.0, 1024.0, 768.0)
    assert (got.width_px, got.height_px) == (2048, 1536)
    assert got.distortion == (-0.1, 0.01, 0.001, 0.002, 0.0)


def test_intrinsics_with_an_unknown_key_are_one_line(tmp_path):
    path = tmp_path / "cam.toml"
    path.write_text(INTRINSICS_TOML + "focal = 3\n")
    with pytest.raises(ConfigError, match=r"unknown key 'focal'; expected fx, fy, cx, cy, width, height"):
        read_intrinsics(path)
