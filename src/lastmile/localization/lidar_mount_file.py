"""The LiDAR mounts file: ``[[lidar_mount]]`` tables, written by ``lastmile calibrate lidar --out`` and
read by the run configuration's ``[stack] lidar_mounts`` so the stack runs on calibrated mounts.

Each table is one LiDAR's base_from_sensor: its position (``x_m``, ``y_m``, ``z_m``) and its attitude
as extrinsic x-y-z Euler angles (``roll_rad``, ``pitch_rad``, ``yaw_rad``), keyed by ``sensor_id`` (the
id without the ``lidar_`` prefix of recordings' frame ids). Other keys the calibration writes beside
them (``source``, ``correction_m``, ``fitness``, ...) are information and are not read.

The reader is strict: a missing or non-numeric pose key, a non-finite value or a LiDAR named twice is
one line naming the table and the key.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from lastmile.core.config import load_toml
from lastmile.core.errors import ConfigError

POSITION_KEYS = ("x_m", "y_m", "z_m")
ANGLE_KEYS = ("roll_rad", "pitch_rad", "yaw_rad")


def mount_row(sensor_id: str, mount: np.ndarray) -> dict[str, Any]:
    """A mount as a ``[[lidar_mount]]`` table (position to 10 µm, angles to 1 µrad)."""
    roll, pitch, yaw = Rotation.from_matrix(mount[:3, :3]).as_euler("xyz")
    x, y, z = (float(v) for v in mount[:3, 3])
    return {
        "sensor_id": sensor_id.removeprefix("lidar_"),
        "x_m": round(x, 5),
        "y_m": round(y, 5),
        "z_m": round(z, 5),
        "roll_rad": round(float(roll), 6),
        "pitch_rad": round(float(pitch), 6),
        "yaw_rad": round(float(yaw), 6),
    }


def read_lidar_mounts(path: Path) -> dict[str, np.ndarray]:
    """The (4, 4) base_from_sensor of every LiDAR in a mounts file, by sensor id.

    Raises:
        ConfigError: the file is missing or not TOML, has no ``[[lidar_mount]]`` table, or a table is
            malformed (one line naming it).
    """
    data = load_toml(path)
    rows = data.get("lidar_mount")
    if not isinstance(rows, list) or not rows:
        raise ConfigError(
            f"{path}: expected [[lidar_mount]] tables (from `lastmile calibrate lidar --out`), got none"
        )
    mounts: dict[str, np.ndarray] = {}
    for i, row in enumerate(rows):
        where = f"{path}: lidar_mount[{i}]"
        sensor_id = _sensor_id(row, where)
        if sensor_id in mounts:
            raise ConfigError(f"{where}: expected each LiDAR once, got sensor_id {sensor_id!r} again")
        mounts[sensor_id] = _mount(row, where)
    return mounts


def _sensor_id(row: Any, where: str) -> str:
    if not isinstance(row, dict):
        raise ConfigError(f"{where}: expected a table, got {type(row).__name__}")
    sensor_id = row.get("sensor_id")
    if not isinstance(sensor_id, str) or not sensor_id.strip():
        raise ConfigError(f"{where}.sensor_id: expected the LiDAR's id (a string), got {sensor_id!r}")
    return sensor_id.removeprefix("lidar_")


def _mount(row: dict[str, Any], where: str) -> np.ndarray:
    values = []
    for key in (*POSITION_KEYS, *ANGLE_KEYS):
        value = row.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ConfigError(f"{where}.{key}: expected a finite number, got {value!r}")
        values.append(float(value))
    mount = np.eye(4)
    mount[:3, :3] = Rotation.from_euler("xyz", values[3:]).as_matrix()
    mount[:3, 3] = values[:3]
    return mount


def check_covers(mounts: dict[str, np.ndarray], lidar_ids: list[str] | tuple[str, ...], where: str) -> None:
    """Raise a :class:`ConfigError` unless ``mounts`` names exactly the vehicle's LiDARs.

    A LiDAR missing from the file would silently keep its nominal mount; one the vehicle does not
    have is most likely a file of another vehicle.
    """
    missing = sorted(set(lidar_ids) - set(mounts))
    extra = sorted(set(mounts) - set(lidar_ids))
    if missing or extra:
        raise ConfigError(
            f"{where}: expected a mount for each of the vehicle's LiDARs {sorted(lidar_ids)}, got "
            f"{sorted(mounts)}"
            + (f" (missing {missing})" if missing else "")
            + (f" (unknown {extra})" if extra else "")
        )
