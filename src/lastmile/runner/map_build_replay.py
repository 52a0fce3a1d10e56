"""``lastmile map build``: a point-cloud map from a recording's LiDAR sweeps and the vehicle's own poses.

The recording (a black-box MCAP, or any file the recorder wrote) holds every LiDAR sweep in its
sensor's frame, the mounts on ``/tf`` (``base_link -> lidar_<id>``), the estimated pose
(``map -> base_link``) and, on ``/localization/estimate``, the estimate itself with its source and
sigma. Sweeps stamped alike form a rig frame; each is de-skewed with the recorded trajectory, placed
at the recorded pose and refined by registration (:mod:`lastmile.localization.map_build`); frames whose
recorded pose was dead reckoning or too uncertain are left out. The map is written as PCD with a JSON
sidecar (:mod:`lastmile.localization.point_cloud_map`), and its 2-D occupancy map for the ``amcl`` mode
beside it (``MAP.yaml`` + ``MAP.pgm``, ROS map_server's format; :mod:`lastmile.localization.occupancy_map`).

Like ``lidar_calibration_replay.py``, this feeds recorded data to one module alone: no vehicle, no loop.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.core.errors import CalibrationError, MapError
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.localization.map_build import MapBuildConfig, PointCloudMapBuilder, Trajectory, deskew_to_base
from lastmile.localization.occupancy_map import grid_from_points, write_grid
from lastmile.localization.point_cloud_map import (
    PointCloudMapInfo,
    extent,
    percentile_or_none,
    write_point_cloud_map,
)
from lastmile.recorder.foxglove_views import BASE_FRAME, MAP_FRAME, TF_TOPIC
from lastmile.recorder.replay import Recording, read_recording
from lastmile.runner.lidar_calibration_replay import recorded_mounts, recorded_poses

ESTIMATE_TOPIC = "/localization/estimate"


@dataclass(frozen=True, slots=True, kw_only=True)
class MapBuildResult:
    """The map written and what went into it."""

    info: PointCloudMapInfo
    frames_skipped_pose: int
    """Rig frames left out because the recorded pose was dead reckoning, too uncertain or absent."""


def build_map(recording: Path, out: Path, config: MapBuildConfig) -> MapBuildResult:
    """Build the map of ``recording`` and write it to ``out`` (PCD) and ``out``.json.

    Raises:
        RecordingError: the file cannot be read.
        MapError: no LiDAR sweeps, no mounts for them, no recorded poses, or no frame placed.
    """
    rec = read_recording(recording)
    frames = _rig_frames(rec, recording)
    mounts = recorded_mounts(rec)
    missing = sorted({f"lidar_{s.sensor_id}" for sweeps in frames.values() for s in sweeps} - set(mounts))
    if missing:
        raise MapError(f"{recording}: expected a {BASE_FRAME} -> {missing[0]} mount on {TF_TOPIC}, got none")
    try:
        stamps, poses = recorded_poses(rec)
    except CalibrationError:
        raise MapError(
            f"{recording}: expected the vehicle's poses ({MAP_FRAME} -> {BASE_FRAME} on {TF_TOPIC}), got none"
        ) from None
    trajectory = Trajectory.from_matrices(stamps, poses)
    estimates = [e for e in rec.on(ESTIMATE_TOPIC) if isinstance(e, LocalizationEstimate)]
    est_t = np.array([int(e.stamp) for e in estimates], dtype=np.int64)
    builder = PointCloudMapBuilder(config)
    skipped = 0
    for stamp_us in sorted(frames):
        pose_ok, est = _pose_usable(estimates, est_t, stamp_us, config.max_pose_std_m)
        sweeps = frames[stamp_us]
        ends = np.array([stamp_us + int(np.max(s.points[:, 5], initial=0.0)) for s in sweeps])
        if not pose_ok or not trajectory.covers(np.append(ends, stamp_us)):
            skipped += 1
            continue
        xy, yaw = trajectory.at(np.array([stamp_us]))
        if not builder.wants(float(xy[0, 0]), float(xy[0, 1]), float(yaw[0])):
            builder.stats.frames_offered += 1
            continue
        pts = np.concatenate(
            [
                deskew_to_base(
                    s.points[:, :3].astype(np.float64),
                    s.points[:, 5].astype(np.float64),
                    stamp_us,
                    mounts[f"lidar_{s.sensor_id}"],
                    trajectory,
                )
                for s in sweeps
            ]
        )
        std_m, yaw_std = (est.pos_std_m, est.yaw_std_rad) if est is not None else (None, None)
        builder.add(pts, float(xy[0, 0]), float(xy[0, 1]), float(yaw[0]), std_m, yaw_std)
    points = builder.points()
    st = builder.stats
    if len(points) == 0:
        raise MapError(
            f"{recording}: expected rig frames with a usable recorded pose, got none placed "
            f"({len(frames)} frames, {skipped} without an absolute pose within "
            f"{config.max_pose_std_m} m)"
        )
    lo, hi = extent(points)
    info = PointCloudMapInfo(
        frame=MAP_FRAME,
        voxel_m=config.voxel_m,
        source=str(recording),
        points=len(points),
        extent_min_m=lo,
        extent_max_m=hi,
        frames_total=len(frames),
        frames_used=st.frames_used,
        frames_registered=st.frames_registered,
        registration_rmse_p50_m=percentile_or_none(st.rmse_m, 50),
        registration_rmse_p95_m=percentile_or_none(st.rmse_m, 95),
        correction_p50_m=percentile_or_none(st.correction_m, 50),
        correction_max_m=percentile_or_none(st.correction_m, 100),
        pose_source=f"{MAP_FRAME} -> {BASE_FRAME} on {TF_TOPIC}"
        + (f", absolute sources per {ESTIMATE_TOPIC}" if estimates else " (no estimates: sigma unknown)"),
    )
    grid_yaml = out.with_suffix(".yaml")
    write_grid(grid_yaml, grid_from_points(points))
    info = dataclasses.replace(info, occupancy_map=grid_yaml.name)
    write_point_cloud_map(out, points, info)
    return MapBuildResult(info=info, frames_skipped_pose=skipped)


def _rig_frames(rec: Recording, path: Path) -> dict[int, list[LidarSweep]]:
    """The recording's sweeps grouped by stamp (one revolution of the rig is stamped alike)."""
    frames: dict[int, list[LidarSweep]] = {}
    for msg in rec.messages:
        if isinstance(msg.message, LidarSweep) and len(msg.message.points):
            frames.setdefault(int(msg.message.stamp), []).append(msg.message)
    if not frames:
        raise MapError(f"{path}: expected LiDAR point clouds (/sensors/lidar/*), got none")
    return frames


def _pose_usable(
    estimates: list[LocalizationEstimate], est_t: np.ndarray, stamp_us: int, max_std_m: float
) -> tuple[bool, LocalizationEstimate | None]:
    """Whether the newest recorded estimate at or before ``stamp_us`` was valid, held by an absolute
    source and within ``max_std_m`` (True when the recording carries no estimates, only ``/tf``), and
    that estimate."""
    if not estimates:
        return True, None
    k = int(np.searchsorted(est_t, stamp_us, side="right")) - 1
    if k < 0:
        return False, None
    est = estimates[k]
    ok = est.valid and est.source is not PositionSource.DEAD_RECKONING and est.pos_std_m <= max_std_m
    return ok, est
