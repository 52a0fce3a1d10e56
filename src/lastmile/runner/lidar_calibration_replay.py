"""``lastmile calibrate lidar``: calibrate a recording's LiDARs against a reference one.

The black box records every LiDAR sweep in its sensor's own frame and, on ``/tf``, the mounts the
vehicle used (``base_link -> lidar_<id>``) and the estimated pose (``map -> base_link``). For each other
LiDAR, sweeps are paired with the reference sweep nearest in time; the pairs where the vehicle moved
least between the two captures and over the sweep (from the recorded pose) are the "stationary-ish"
frames. The reference sweep is carried into the base frame at the other sweep's capture with the
recorded pose (``base_then_from_base_now``), so what remains of the vehicle's motion is the skew within
a sweep. Each frame is calibrated (``localization/lidar_calibration.py``), and the mount is the mean of
the frames' (translation mean, rotation chordal mean), with their spread reported.

Like ``localization_replay.py``, this feeds recorded data to one module alone, no vehicle and no loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from scipy.spatial.transform import Rotation

from lastmile.core.errors import CalibrationError, ConfigError
from lastmile.core.sensor_frames import LidarSweep
from lastmile.localization.lidar_calibration import (
    IcpCalibrationConfig,
    LidarCalibration,
    calibrate_by_icp,
    calibrate_by_planes,
    mount_difference,
)
from lastmile.localization.lidar_mount_file import mount_row
from lastmile.recorder.foxglove_views import BASE_FRAME, MAP_FRAME, TF_TOPIC
from lastmile.recorder.replay import Recording, read_recording


class Method(Enum):
    """Calibration method of the command."""

    ICP = "icp"
    PLANES = "planes"


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameResult:
    """One sweep pair's calibration.

    Attributes:
        stamp_us: the other LiDAR's capture.
        motion_m: how far the vehicle moved between the two captures, m (the sweep choice's criterion).
        calibration: the result, or None with ``error`` set.
        error: why the frame failed.
    """

    stamp_us: int
    motion_m: float
    calibration: LidarCalibration | None
    error: str | None


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorResult:
    """One LiDAR's calibrated mount.

    Attributes:
        frame_id: the LiDAR's transform-tree frame (``lidar_left``).
        nominal: (4, 4) recorded base_from_sensor.
        calibrated: (4, 4) mean of the frames' mounts, or None when every frame failed.
        frames: each frame's result.
        spread_m: largest distance of a frame's mount from the mean, m.
        spread_rad: largest angle of a frame's mount from the mean, rad.
    """

    frame_id: str
    nominal: np.ndarray
    calibrated: np.ndarray | None
    frames: tuple[FrameResult, ...]
    spread_m: float
    spread_rad: float


def recorded_mounts(rec: Recording) -> dict[str, np.ndarray]:
    """base_from_sensor of every LiDAR frame on the recording's ``/tf`` (the last one seen)."""
    mounts: dict[str, np.ndarray] = {}
    for view in rec.views:
        if view.topic != TF_TOPIC:
            continue
        for tf in _transforms(view.message):
            if tf.parent_frame_id == BASE_FRAME and str(tf.child_frame_id).startswith("lidar_"):
                mounts[str(tf.child_frame_id)] = _matrix(tf)
    return mounts


def recorded_poses(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """(stamps_us (K,), map_from_base (K, 4, 4)) of the recorded ``map -> base_link``, time-ordered."""
    stamps: list[int] = []
    poses: list[np.ndarray] = []
    for view in rec.views:
        if view.topic != TF_TOPIC:
            continue
        for tf in _transforms(view.message):
            if tf.parent_frame_id == MAP_FRAME and tf.child_frame_id == BASE_FRAME:
                stamps.append(int(tf.timestamp.seconds) * 1_000_000 + int(tf.timestamp.nanos) // 1000)
                poses.append(_matrix(tf))
    if not stamps:
        raise CalibrationError(f"{rec.path}: expected map -> {BASE_FRAME} transforms on {TF_TOPIC}, got none")
    order = np.argsort(np.array(stamps), kind="stable")
    return np.array(stamps, dtype=np.int64)[order], np.array(poses)[order]


def calibrate_recording(
    path: Path,
    reference: str,
    method: Method,
    frames: int,
    config: IcpCalibrationConfig | None = None,
) -> tuple[list[SensorResult], np.ndarray]:
    """Calibrate every other LiDAR of a recording against ``reference`` (a frame id, ``lidar_front``).

    Returns:
        Each other LiDAR's result, and the reference's recorded mount.

    Raises:
        RecordingError: the file cannot be read.
        ConfigError: an unknown reference, or ``frames`` < 1.
        CalibrationError: no LiDAR sweeps, no mounts, or no pose on ``/tf``.
    """
    if frames < 1:
        raise ConfigError(f"--frames: expected at least 1, got {frames}")
    rec = read_recording(path)
    mounts = recorded_mounts(rec)
    sweeps: dict[str, list[LidarSweep]] = {}
    for msg in rec.messages:
        if isinstance(msg.message, LidarSweep):
            sweeps.setdefault(f"lidar_{msg.message.sensor_id}", []).append(msg.message)
    if not sweeps:
        raise CalibrationError(f"{path}: expected LiDAR point clouds (/sensors/lidar/*), got none")
    if reference not in sweeps or reference not in mounts:
        have = sorted(set(sweeps) & set(mounts))
        raise ConfigError(
            f"--reference: expected one of {have} (LiDARs with sweeps and a mount), got {reference!r}"
        )
    stamps, poses = recorded_poses(rec)
    out = []
    for frame_id in sorted(set(sweeps) - {reference}):
        if frame_id not in mounts:
            raise CalibrationError(
                f"{path}: expected a {BASE_FRAME} -> {frame_id} mount on {TF_TOPIC}, got none"
            )
        pairs = _quiet_pairs(sweeps[reference], sweeps[frame_id], stamps, poses, frames)
        results = [
            _calibrate_pair(ref, oth, mounts[reference], mounts[frame_id], stamps, poses, method, config)
            for ref, oth in pairs
        ]
        out.append(_summarise(frame_id, mounts[frame_id], results))
    return out, mounts[reference]


def _quiet_pairs(
    ref: list[LidarSweep], other: list[LidarSweep], stamps: np.ndarray, poses: np.ndarray, n: int
) -> list[tuple[LidarSweep, LidarSweep]]:
    """The ``n`` (reference, other) pairs, nearest in time, over which the vehicle moved least.

    Pairs where either sweep is nearly empty (fewer than 100 points: a blocked or blinded unit) come
    last, so they are used only when nothing else is left (and then fail with their reason).
    """
    ref_t = np.array([int(s.stamp) for s in ref], dtype=np.int64)
    scored = []
    for oth in other:
        t = int(oth.stamp)
        k = int(np.argmin(np.abs(ref_t - t)))
        # Motion between the captures plus over one sweep period (the skew within a sweep).
        sweep_us = int(max(float(np.max(oth.points[:, 5], initial=0.0)), 1.0))
        moved = _moved_m(stamps, poses, int(ref_t[k]), t) + _moved_m(stamps, poses, t, t + sweep_us)
        sparse = min(len(oth.points), len(ref[k].points)) < 100
        scored.append((sparse, moved, t, ref[k], oth))
    scored.sort(key=lambda s: (s[0], s[1], s[2]))
    return [(r, o) for _, _, _, r, o in scored[:n]]


def _calibrate_pair(
    ref: LidarSweep,
    oth: LidarSweep,
    ref_mount: np.ndarray,
    nominal: np.ndarray,
    stamps: np.ndarray,
    poses: np.ndarray,
    method: Method,
    config: IcpCalibrationConfig | None,
) -> FrameResult:
    t_ref, t_oth = int(ref.stamp), int(oth.stamp)
    # base at t_oth from base at t_ref: the reference cloud where the other LiDAR's base frame was.
    then_from_now = np.linalg.inv(_pose_at(stamps, poses, t_oth)) @ _pose_at(stamps, poses, t_ref)
    to_base = then_from_now @ ref_mount
    ref_pts = ref.points[:, :3].astype(np.float64) @ to_base[:3, :3].T + to_base[:3, 3]
    oth_pts = oth.points[:, :3].astype(np.float64)
    motion = _moved_m(stamps, poses, t_ref, t_oth)
    try:
        if method is Method.ICP:
            cal = calibrate_by_icp(ref_pts, oth_pts, nominal, config)
        else:
            cal = calibrate_by_planes(ref_pts, oth_pts, nominal, to_base[:3, 3], config)
    except CalibrationError as exc:
        return FrameResult(stamp_us=t_oth, motion_m=motion, calibration=None, error=str(exc))
    return FrameResult(stamp_us=t_oth, motion_m=motion, calibration=cal, error=None)


def _summarise(frame_id: str, nominal: np.ndarray, results: list[FrameResult]) -> SensorResult:
    good = [r.calibration.base_from_sensor for r in results if r.calibration is not None]
    if not good:
        return SensorResult(
            frame_id=frame_id,
            nominal=nominal,
            calibrated=None,
            frames=tuple(results),
            spread_m=0.0,
            spread_rad=0.0,
        )
    mean = np.eye(4)
    mean[:3, :3] = Rotation.from_matrix(np.array([g[:3, :3] for g in good])).mean().as_matrix()
    mean[:3, 3] = np.mean([g[:3, 3] for g in good], axis=0)
    diffs = [mount_difference(mean, g) for g in good]
    return SensorResult(
        frame_id=frame_id,
        nominal=nominal,
        calibrated=mean,
        frames=tuple(results),
        spread_m=max(d[0] for d in diffs),
        spread_rad=max(d[1] for d in diffs),
    )


def write_mounts(path: Path, reference: str, ref_mount: np.ndarray, results: list[SensorResult]) -> bool:
    """Write ``[[lidar_mount]]`` tables: the reference's recorded mount and each calibrated one.

    Returns:
        False, and nothing written, when no LiDAR was calibrated.
    """
    if all(r.calibrated is None for r in results):
        return False
    rows = [{**mount_row(reference, ref_mount), "source": "reference"}]
    for r in results:
        if r.calibrated is None:
            continue
        corr_m, corr_rad = mount_difference(r.nominal, r.calibrated)
        fits = [f.calibration.fitness for f in r.frames if f.calibration is not None]
        rows.append(
            {
                **mount_row(r.frame_id, r.calibrated),
                "source": "calibrated",
                "correction_m": round(corr_m, 5),
                "correction_deg": round(math.degrees(corr_rad), 5),
                "fitness": round(float(np.mean(fits)), 4),
                "frames": len(fits),
            }
        )
    path.write_text(
        "# LiDAR mounts (base_from_sensor) from `lastmile calibrate lidar`.\n"
        + tomli_w.dumps({"lidar_mount": rows})
    )
    return True


TABLE_COLUMNS = (
    "LiDAR",
    "mount before",
    "mount after",
    "correction cm",
    "correction deg",
    "fitness",
    "RMSE cm",
    "frames ok",
    "spread / failure",
)


def table_rows(results: list[SensorResult]) -> list[tuple[str, ...]]:
    """(LiDAR, before, after, correction cm, correction deg, fitness, RMSE cm, frames ok, spread)."""
    rows: list[tuple[str, ...]] = []
    for r in results:
        fits = [f.calibration for f in r.frames if f.calibration is not None]
        before = _short(r.nominal)
        if r.calibrated is None:
            reason = r.frames[0].error if r.frames else "no frames"
            rows.append((r.frame_id, before, "failed", "", "", "", "", f"0/{len(r.frames)}", str(reason)))
            continue
        corr_m, corr_rad = mount_difference(r.nominal, r.calibrated)
        rows.append(
            (
                r.frame_id,
                before,
                _short(r.calibrated),
                f"{corr_m * 100:.2f}",
                f"{math.degrees(corr_rad):.3f}",
                f"{np.mean([c.fitness for c in fits]):.2f}",
                f"{np.mean([c.rmse_m for c in fits]) * 100:.2f}",
                f"{len(fits)}/{len(r.frames)}",
                f"{r.spread_m * 100:.2f} cm / {math.degrees(r.spread_rad):.3f} deg",
            )
        )
    return rows


def _short(mount: np.ndarray) -> str:
    roll, pitch, yaw = np.degrees(Rotation.from_matrix(mount[:3, :3]).as_euler("xyz"))
    x, y, z = mount[:3, 3]
    return f"({x:.3f}, {y:.3f}, {z:.3f}) m rpy ({roll:.2f}, {pitch:.2f}, {yaw:.2f}) deg"


def _transforms(message: Any) -> list[Any]:
    """The FrameTransform(s) of a ``/tf`` view (``FrameTransforms`` or a single ``FrameTransform``)."""
    return list(message.transforms) if hasattr(message, "transforms") else [message]


def _matrix(tf: Any) -> np.ndarray:
    out = np.eye(4)
    q = tf.rotation
    out[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    out[:3, 3] = (tf.translation.x, tf.translation.y, tf.translation.z)
    return out


def _pose_at(stamps: np.ndarray, poses: np.ndarray, t_us: int) -> np.ndarray:
    """map_from_base at ``t_us``: linear in position and yaw between the recorded poses (held at the ends)."""
    k = int(np.searchsorted(stamps, t_us))
    if k <= 0:
        return poses[0]
    if k >= len(stamps):
        return poses[-1]
    t0, t1 = int(stamps[k - 1]), int(stamps[k])
    a = 0.0 if t1 == t0 else (t_us - t0) / (t1 - t0)
    p0, p1 = poses[k - 1], poses[k]
    yaw0 = math.atan2(p0[1, 0], p0[0, 0])
    yaw1 = yaw0 + math.remainder(math.atan2(p1[1, 0], p1[0, 0]) - yaw0, 2 * math.pi)
    out = np.eye(4)
    yaw = yaw0 + a * (yaw1 - yaw0)
    out[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    out[:3, 3] = p0[:3, 3] + a * (p1[:3, 3] - p0[:3, 3])
    return out


def _moved_m(stamps: np.ndarray, poses: np.ndarray, t0_us: int, t1_us: int) -> float:
    a, b = _pose_at(stamps, poses, t0_us), _pose_at(stamps, poses, t1_us)
    shift_m, turn_rad = mount_difference(a, b)
    # A turn moves the far points most: count it as the motion of a point 10 m away.
    return shift_m + 10.0 * turn_rad
