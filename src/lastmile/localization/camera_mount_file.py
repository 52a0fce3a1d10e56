"""Camera mounts on file: the ``[[camera_mount]]`` tables ``lastmile calibrate camera`` writes and the
stack's ``[stack] camera_mounts`` reads.

A mount is the camera's body frame (x along the optical axis, y left, z up: ROS's ``camera_link``) in a
parent frame: the optical centre ``x_m, y_m, z_m`` and ``roll_rad, pitch_rad, yaw_rad``, the rotation
``Rz(yaw) Ry(pitch) Rx(roll)`` (extrinsic x-y-z, as ``[[lidar_mount]]`` rows; positive pitch looks
down, as :meth:`PinholeCamera.mounted`). A camera looking straight ahead has all three angles 0. The
optical frame (x right, y down, z along the axis) follows by :data:`OPTICAL_FROM_BODY`;
``camera_from_parent`` maps parent points into it.

Each row gives the camera in the vehicle's base frame (what the stack uses). Rows written by the
calibration also carry, for the record, the camera in the LiDAR frame (``in_lidar``: what was measured),
the LiDAR's mount used (``lidar_in_base``), and the fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from scipy.spatial.transform import Rotation

from lastmile.core.camera_model import OPTICAL_FROM_BODY
from lastmile.core.config import from_mapping, load_toml
from lastmile.core.errors import ConfigError


@dataclass(frozen=True, slots=True, kw_only=True)
class MountPose:
    """A camera body frame (or a LiDAR) in a parent frame: position (m) and roll, pitch, yaw (rad)."""

    x_m: float
    y_m: float
    z_m: float
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0

    def parent_from_child(self) -> np.ndarray:
        """(4, 4) the pose as a transform (child points into the parent frame)."""
        out = np.eye(4)
        out[:3, :3] = Rotation.from_euler("xyz", [self.roll_rad, self.pitch_rad, self.yaw_rad]).as_matrix()
        out[:3, 3] = (self.x_m, self.y_m, self.z_m)
        return out

    @staticmethod
    def of(parent_from_child: np.ndarray) -> MountPose:
        """The pose of a (4, 4) transform."""
        roll, pitch, yaw = Rotation.from_matrix(parent_from_child[:3, :3]).as_euler("xyz")
        x, y, z = (float(v) for v in parent_from_child[:3, 3])
        return MountPose(
            x_m=x, y_m=y, z_m=z, roll_rad=float(roll), pitch_rad=float(pitch), yaw_rad=float(yaw)
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraMountRow:
    """One ``[[camera_mount]]`` table.

    Attributes:
        camera_id: the camera (``front``, ``rear``).
        x_m, y_m, z_m, roll_rad, pitch_rad, yaw_rad: its body frame in the base frame.
        source: how the row was made (``calibrated``).
        correction_m, correction_deg: the calibration's change from the nominal mount.
        views: views the calibration used.
        rmse_m: its point-to-plane RMSE, m.
        normal_spread_deg: the board normals' RMS tilt towards their least-covered direction.
        in_lidar: the camera body frame in the LiDAR frame (what the calibration measured).
        lidar_in_base: the LiDAR's mount it was carried into the base frame with.
    """

    camera_id: str
    x_m: float
    y_m: float
    z_m: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    source: str = ""
    correction_m: float | None = None
    correction_deg: float | None = None
    views: int | None = None
    rmse_m: float | None = None
    normal_spread_deg: float | None = None
    in_lidar: MountPose | None = None
    lidar_in_base: MountPose | None = None

    def camera_from_base(self) -> np.ndarray:
        """(4, 4) base points into the camera's optical frame."""
        pose = MountPose(
            x_m=self.x_m, y_m=self.y_m, z_m=self.z_m, roll_rad=self.roll_rad, pitch_rad=self.pitch_rad,
            yaw_rad=self.yaw_rad,
        )  # fmt: skip
        return camera_from_parent(pose)


def camera_from_parent(pose: MountPose) -> np.ndarray:
    """(4, 4) parent points into the optical frame of a camera whose body frame is at ``pose``."""
    parent_from_body = pose.parent_from_child()
    out = np.eye(4)
    out[:3, :3] = OPTICAL_FROM_BODY @ parent_from_body[:3, :3].T
    out[:3, 3] = -out[:3, :3] @ parent_from_body[:3, 3]
    return out


def body_pose(camera_from_parent_: np.ndarray) -> MountPose:
    """The camera body frame's pose in the parent frame, from (4, 4) ``camera_from_parent``."""
    rot = camera_from_parent_[:3, :3]
    parent_from_body = np.eye(4)
    parent_from_body[:3, :3] = rot.T @ OPTICAL_FROM_BODY
    parent_from_body[:3, 3] = -rot.T @ camera_from_parent_[:3, 3]
    return MountPose.of(parent_from_body)


def read_camera_mounts(path: Path) -> dict[str, np.ndarray]:
    """``camera_from_base`` (4, 4) by camera id from a ``[[camera_mount]]`` file.

    Raises:
        ConfigError: the file is missing or not TOML, has other top-level keys, no rows, a row with an
            unknown or missing key or a wrong type, or the same camera twice.
    """
    data = load_toml(path)
    extra = sorted(set(data) - {"camera_mount"})
    if extra:
        raise ConfigError(f"{path}: unknown key {extra[0]!r}; expected only [[camera_mount]] tables")
    rows = data.get("camera_mount")
    if not isinstance(rows, list) or not rows:
        raise ConfigError(f"{path}: expected [[camera_mount]] tables, got none")
    mounts: dict[str, np.ndarray] = {}
    for i, raw in enumerate(rows):
        row = from_mapping(CameraMountRow, raw, f"{path}: camera_mount[{i}]")
        if row.camera_id in mounts:
            raise ConfigError(
                f"{path}: camera_mount[{i}]: expected each camera once, got {row.camera_id!r} again"
            )
        mounts[row.camera_id] = row.camera_from_base()
    return mounts


def check_covers(mounts: dict[str, Any], camera_ids: tuple[str, ...], where: str) -> None:
    """Raise unless ``mounts`` names exactly the vehicle's cameras."""
    missing = sorted(set(camera_ids) - set(mounts))
    unknown = sorted(set(mounts) - set(camera_ids))
    if missing or unknown:
        got = f"missing {missing}" if missing else ""
        got += ("; " if got and unknown else "") + (f"not on this vehicle {unknown}" if unknown else "")
        raise ConfigError(f"{where}: expected a mount for each camera {sorted(camera_ids)}, got {got}")


def mount_table(row: CameraMountRow) -> dict[str, Any]:
    """A row as a TOML table (None fields left out, angles and lengths rounded to um / urad)."""
    out: dict[str, Any] = {}
    for name in CameraMountRow.__dataclass_fields__:
        value = getattr(row, name)
        if value is None or value == "":
            continue
        if isinstance(value, MountPose):
            value = {k: round(getattr(value, k), 6) for k in MountPose.__dataclass_fields__}
        elif isinstance(value, float):
            value = round(value, 6)
        out[name] = value
    return out


def read_rows(path: Path) -> list[CameraMountRow]:
    """The rows of a ``[[camera_mount]]`` file, checked as :func:`read_camera_mounts` checks them."""
    read_camera_mounts(path)
    return [
        from_mapping(CameraMountRow, raw, f"{path}: camera_mount[{i}]")
        for i, raw in enumerate(load_toml(path)["camera_mount"])
    ]


def merge_camera_mounts(path: Path, row: CameraMountRow) -> None:
    """Write ``row`` into the mounts file at ``path``: the other cameras' rows of an existing file are
    kept (one camera is calibrated at a time; the stack needs them all), this camera's replaced.

    Raises:
        ConfigError: an existing file that is not a valid ``[[camera_mount]]`` file (left untouched).
    """
    rows = read_rows(path) if path.exists() else []
    write_camera_mounts(path, [r for r in rows if r.camera_id != row.camera_id] + [row])


def write_camera_mounts(path: Path, rows: list[CameraMountRow]) -> None:
    """Write ``[[camera_mount]]`` tables with a header naming the frames."""
    header = (
        "# Camera mounts from `lastmile calibrate camera`: each camera's body frame (x along the optical\n"
        "# axis, y left, z up) in the base frame; roll/pitch/yaw are Rz(yaw) Ry(pitch) Rx(roll), rad.\n"
        "# in_lidar: the same in the LiDAR frame (what was measured); lidar_in_base: the LiDAR mount used.\n"
    )
    path.write_text(header + tomli_w.dumps({"camera_mount": [mount_table(r) for r in rows]}))


def degrees_text(pose: MountPose) -> str:
    """``(x, y, z) m rpy (r, p, y) deg``."""
    r, p, y = (math.degrees(v) for v in (pose.roll_rad, pose.pitch_rad, pose.yaw_rad))
    return f"({pose.x_m:.3f}, {pose.y_m:.3f}, {pose.z_m:.3f}) m rpy ({r:.2f}, {p:.2f}, {y:.2f}) deg"
