"""Read a drive from a ROS 1 bag or a rosbag2 (SQLite or MCAP) with ``rosbags``: no ROS install needed.

Messages: ``sensor_msgs/Imu`` (yaw rate, longitudinal acceleration), ``sensor_msgs/NavSatFix`` (GNSS),
``nav_msgs/Odometry`` (wheel speed: ``twist.twist.linear.x`` in the child frame). Stamps are the
message headers' (sensor time), not the bag's receive time.

The IMU may be mounted in any orientation: its up axis is the mean specific force over the recording
(a vehicle's accelerations average out over minutes; gravity does not), the yaw rate is the angular
velocity along it, and the longitudinal acceleration is along the IMU axis named ``forward_axis``
(REP 103: x forward), made horizontal.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.gnss_messages import ACCURACY_FLOOR_M, GnssQuality
from lastmile.recorder.recorded_drive import DriveFormatError, GeoFix, ImuSamples, WheelSamples

IMU_TYPE = "sensor_msgs/msg/Imu"
FIX_TYPE = "sensor_msgs/msg/NavSatFix"
ODOM_TYPE = "nav_msgs/msg/Odometry"
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
# NavSatStatus: -1 no fix, 0 unaugmented, 1 SBAS, 2 GBAS (drivers report RTK this way).
_STATUS = {0: GnssQuality.SINGLE, 1: GnssQuality.DGNSS, 2: GnssQuality.RTK_FIXED}


@dataclass(frozen=True, slots=True)
class BagTopics:
    """Which topics to read; None picks the only topic of that type (an error when there are several)."""

    imu: str | None = None
    fix: str | None = None
    odom: str | None = None


@dataclass(frozen=True, slots=True)
class BagStreams:
    fixes: list[GeoFix]
    imu: ImuSamples | None
    wheel: WheelSamples | None
    topics: tuple[str, ...]
    skipped_no_fix: int


def parse_axis(text: str) -> np.ndarray:
    """'x', '-y', ... -> unit vector in the IMU frame."""
    sign = -1.0 if text.startswith("-") else 1.0
    axis = _AXES.get(text.lstrip("+-"))
    if axis is None:
        raise DriveFormatError(f"IMU forward axis: expected one of x, y, z, -x, -y, -z, got {text!r}")
    return sign * np.array(axis)


def read_rosbag(path: Path, topics: BagTopics | None = None, forward_axis: str = "x") -> BagStreams:
    """Read IMU, GNSS and wheel-odometry messages of a bag.

    Raises:
        DriveFormatError: an unreadable bag, an ambiguous or missing topic, or a bad message (named by
            topic and index).
    """
    from rosbags.highlevel import AnyReader, AnyReaderError

    forward = parse_axis(forward_axis)
    topics = topics or BagTopics()
    if not path.exists():
        raise DriveFormatError(f"{path}: expected a ROS bag (file or rosbag2 directory), found none")
    try:
        with AnyReader([path]) as reader:
            chosen = {
                kind: _pick(path, reader.connections, msgtype, name)
                for kind, msgtype, name in (
                    ("imu", IMU_TYPE, topics.imu),
                    ("fix", FIX_TYPE, topics.fix),
                    ("odom", ODOM_TYPE, topics.odom),
                )
            }
            rows: dict[str, list[Any]] = {"imu": [], "fix": [], "odom": []}
            by_topic = {topic: kind for kind, topic in chosen.items() if topic is not None}
            connections = [c for c in reader.connections if c.topic in by_topic]
            for connection, _, raw in reader.messages(connections=connections):
                kind = by_topic[connection.topic]
                where = f"{path}: {connection.topic} message {len(rows[kind]) + 1}"
                rows[kind].append((where, reader.deserialize(raw, connection.msgtype)))
    except AnyReaderError as exc:
        raise DriveFormatError(f"{path}: expected a readable ROS 1 bag or rosbag2, got: {exc}") from None
    fixes, skipped = _fixes(rows["fix"])
    return BagStreams(
        fixes=fixes,
        imu=_imu(path, rows["imu"], forward) if rows["imu"] else None,
        wheel=_wheel(rows["odom"]) if rows["odom"] else None,
        topics=tuple(t for t in chosen.values() if t is not None),
        skipped_no_fix=skipped,
    )


def _pick(path: Path, connections: Any, msgtype: str, wanted: str | None) -> str | None:
    found = sorted({c.topic for c in connections if c.msgtype == msgtype})
    if wanted is not None:
        if wanted not in found:
            raise DriveFormatError(
                f"{path}: expected topic {wanted!r} of type {msgtype}, found {found or 'none'}"
            )
        return wanted
    if len(found) > 1:
        raise DriveFormatError(f"{path}: expected one {msgtype} topic, found {found}; name the one to use")
    return found[0] if found else None


def _stamp_us(where: str, msg: Any) -> int:
    stamp = msg.header.stamp
    us = int(stamp.sec) * 1_000_000 + int(stamp.nanosec) // 1000
    if us <= 0:
        raise DriveFormatError(
            f"{where}: expected a header stamp after 1970, got {stamp.sec}.{stamp.nanosec:09d}"
        )
    return us


def _finite(where: str, name: str, values: np.ndarray) -> np.ndarray:
    if not np.isfinite(values).all():
        raise DriveFormatError(f"{where} ({name}): expected finite values, got {values.tolist()}")
    return values


def _imu(path: Path, rows: list[tuple[str, Any]], forward: np.ndarray) -> ImuSamples:
    t = np.empty(len(rows), dtype=np.int64)
    gyro = np.empty((len(rows), 3))
    accel = np.empty((len(rows), 3))
    for i, (where, msg) in enumerate(rows):
        t[i] = _stamp_us(where, msg)
        w, a = msg.angular_velocity, msg.linear_acceleration
        gyro[i] = _finite(where, "angular_velocity", np.array((w.x, w.y, w.z)))
        accel[i] = _finite(where, "linear_acceleration", np.array((a.x, a.y, a.z)))
    mean = accel.mean(axis=0)
    g = float(np.linalg.norm(mean))
    if not 8.8 < g < 10.8:
        raise DriveFormatError(
            f"{path}: expected the IMU's mean specific force to be gravity (9.8 m/s^2) so as to find its up "
            f"axis, got {g:.2f} m/s^2 (acceleration reported without gravity, or in g?)"
        )
    up = mean / g
    horizontal = forward - (forward @ up) * up
    norm = float(np.linalg.norm(horizontal))
    if norm < 0.5:
        raise DriveFormatError(
            f"{path}: the IMU axis given as forward is within 60 deg of its up axis {up.round(2).tolist()}; "
            "name the IMU axis that points forward"
        )
    horizontal /= norm
    order = np.argsort(t, kind="stable")
    return ImuSamples(t[order], (gyro @ up)[order], (accel @ horizontal)[order])


def _fixes(rows: list[tuple[str, Any]]) -> tuple[list[GeoFix], int]:
    fixes: list[GeoFix] = []
    skipped = 0
    for where, msg in rows:
        status = int(msg.status.status)
        if status < 0:
            skipped += 1
            continue
        if status not in _STATUS:
            raise DriveFormatError(f"{where} (status.status): expected -1, 0, 1 or 2, got {status}")
        quality = _STATUS[status]
        lat, lon, alt = _finite(
            where, "latitude/longitude/altitude", np.array((msg.latitude, msg.longitude, msg.altitude))
        )
        cov = np.asarray(msg.position_covariance, dtype=float)
        if int(msg.position_covariance_type) == 0:
            var_e = var_n = ACCURACY_FLOOR_M[quality] ** 2
            var_en = 0.0
        else:
            _finite(where, "position_covariance", cov)
            var_e, var_en, var_n = float(cov[0]), float(cov[1]), float(cov[4])  # ENU, row-major
            if var_e <= 0 or var_n <= 0 or var_en**2 >= var_e * var_n:
                raise DriveFormatError(
                    f"{where} (position_covariance): expected a positive-definite east/north block, got "
                    f"{var_e}, {var_en}, {var_n}"
                )
        fixes.append(
            GeoFix(_stamp_us(where, msg), float(lat), float(lon), float(alt), var_e, var_en, var_n, quality)
        )
    return fixes, skipped


def _wheel(rows: list[tuple[str, Any]]) -> WheelSamples:
    t = np.array([_stamp_us(where, msg) for where, msg in rows], dtype=np.int64)
    v = np.array(
        [
            float(_finite(where, "twist.twist.linear.x", np.array([msg.twist.twist.linear.x]))[0])
            for where, msg in rows
        ]
    )
    order = np.argsort(t, kind="stable")
    return WheelSamples(t[order], v[order])
