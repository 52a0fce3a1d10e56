"""The LiDAR mounts file: what `lastmile calibrate lidar --out` writes, `[stack] lidar_mounts` reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomli_w

from lastmile.core.errors import ConfigError
from lastmile.localization.lidar_mount_file import check_covers, mount_row, read_lidar_mounts
from tests.localization.lidar_scene import pose


def _write(path: Path, rows: list[dict[str, object]]) -> Path:
    path.write_text(tomli_w.dumps({"lidar_mount": rows}))
    return path


def test_rows_round_trip_to_the_mounts(tmp_path: Path) -> None:
    front = pose((2.5, 0.0, 1.9), (0.0, 1.0, 0.5))
    left = pose((1.2, 0.8, 0.9), (1.5, -2.0, 60.0))
    path = _write(
        tmp_path / "m.toml", [mount_row("lidar_front", front), {**mount_row("left", left), "fitness": 0.9}]
    )
    mounts = read_lidar_mounts(path)
    assert sorted(mounts) == ["front", "left"]
    np.testing.assert_allclose(mounts["front"], front, atol=2e-5)
    np.testing.assert_allclose(mounts["left"], left, atol=2e-5)


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ([], "expected [[lidar_mount]] tables"),
        ([{"x_m": 1.0}], "lidar_mount[0].sensor_id: expected the LiDAR's id"),
        (
            [{"sensor_id": "front", "x_m": 0.0, "y_m": 0.0, "z_m": 1.0, "roll_rad": 0.0, "pitch_rad": 0.0}],
            "lidar_mount[0].yaw_rad: expected a finite number, got None",
        ),
        (
            [
                {
                    "sensor_id": "front",
                    "x_m": "1",
                    "y_m": 0.0,
                    "z_m": 1.0,
                    "roll_rad": 0,
                    "pitch_rad": 0,
                    "yaw_rad": 0,
                }
            ],
            "lidar_mount[0].x_m: expected a finite number, got '1'",
        ),
        (
            [
                {
                    "sensor_id": "front",
                    "x_m": float("nan"),
                    "y_m": 0,
                    "z_m": 1,
                    "roll_rad": 0,
                    "pitch_rad": 0,
                    "yaw_rad": 0,
                }
            ],
            "lidar_mount[0].x_m: expected a finite number, got nan",
        ),
        (
            [mount_row("front", np.eye(4)), mount_row("lidar_front", np.eye(4))],
            "lidar_mount[1]: expected each LiDAR once, got sensor_id 'front' again",
        ),
    ],
)
def test_a_bad_file_is_one_line(tmp_path: Path, rows: list[dict[str, object]], message: str) -> None:
    path = _write(tmp_path / "m.toml", rows)
    with pytest.raises(ConfigError) as err:
        read_lidar_mounts(path)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_file_must_name_exactly_the_vehicles_lidars() -> None:
    check_covers({"front": np.eye(4), "left": np.eye(4)}, ("left", "front"), "w")
    with pytest.raises(ConfigError, match=r"missing \['right'\]"):
        check_covers({"front": np.eye(4), "left": np.eye(4)}, ("front", "left", "right"), "w")
    with pytest.raises(ConfigError, match=r"unknown \['roof'\]"):
        check_covers({"front": np.eye(4), "roof": np.eye(4)}, ("front",), "w")
