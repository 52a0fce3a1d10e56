"""The ``amcl`` localization mode's glue: the raw LiDAR chain's clouds in, pose corrections out.

Each rig frame the LiDAR chain has processed gives a planar scan (the nearest return per degree in the
occupancy map's height band, :func:`lastmile.localization.occupancy_map.planar_scan`). The particle
filter (:class:`lastmile.localization.particle_filter.AmclLocalizer`) is initialised once at the EKF's
first valid pose and its sigmas, moved by the EKF's motion between consecutive clouds (expressed in the
previous base frame), weighed by the scan; its mean and covariance are fused by the EKF at the cloud's
stamp (``PoseEkf.update_pose`` with source AMCL) along the directions the particles pin down, when the
filter is not recovering (injecting random particles). Only the map and the
stack's own sensor data are used, never the simulator's truth.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.geometry import SE2
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.localization.amcl_localization import AmclSettings
from lastmile.localization.ekf import PoseEkf
from lastmile.localization.occupancy_map import planar_scan
from lastmile.localization.particle_filter import AmclLocalizer
from lastmile.localization.scan_match_localization import ScanMatchMeasurement
from lastmile.perception.pipeline import LidarPipelineResult

_INIT_MIN_STD = (0.1, 0.1, math.radians(2.0))
"""Floor of the initial particle spread (x, y, yaw): the EKF's own sigma on RTK is a few centimetres,
narrower than the likelihood field's 0.2 m can refine."""


@dataclass(slots=True)
class AmclStats:
    """Counters for the run's report."""

    clouds: int = 0
    filter_updates: int = 0
    updates: int = 0
    not_confident: int = 0
    """Filter updates not fused: recovering (random injection over the limit)."""
    gate_rejections: int = 0
    reseeds: int = 0
    """Restarts of the particles at the EKF's RTK-held pose after ``reseed_after`` refusals in a row."""
    cpu_ms: list[float] = field(default_factory=list)
    """This thread's CPU time per cloud (scan, motion, filter update, EKF update; reporting only)."""


class AmclFusion:
    """Planar scans from the LiDAR chain into the particle filter, its estimate into the pose EKF."""

    def __init__(self, settings: AmclSettings) -> None:
        self.settings = settings
        self.filter = AmclLocalizer(
            settings.load_map(), settings.filter, np.random.default_rng(settings.seed)
        )
        self.stats = AmclStats()
        self._last_stamp_us: int | None = None
        self._last_pose: SE2 | None = None
        self._disagreements = 0  # consecutive filter updates refused (gate) or recovering

    def fuse(self, ekf: PoseEkf, result: LidarPipelineResult) -> None:
        """Step the filter on ``result``'s cloud once (a cloud already used is skipped); nothing before
        the EKF has a valid pose to start the particles from."""
        stamp = result.cloud.stamp
        if self._last_stamp_us == int(stamp) or not ekf.initialised:
            return
        est = ekf.estimate(stamp)
        if self._last_pose is None and not est.valid:
            return
        self._last_stamp_us = int(stamp)
        start = time.thread_time()
        self._step(ekf, result, est)
        self.stats.cpu_ms.append((time.thread_time() - start) * 1e3)

    def _step(self, ekf: PoseEkf, result: LidarPipelineResult, est: LocalizationEstimate) -> None:
        st, s = self.stats, self.settings
        st.clouds += 1
        pose = est.map_from_base
        # A filter that has lost the pose (random particles converged elsewhere) is refused by the EKF's
        # gate frame after frame; while RTK holds the EKF, it restarts the particles at the EKF's pose
        # (ROS amcl is re-seeded from an initial pose the same way). Never from dead reckoning.
        reseed = self._disagreements >= s.reseed_after and est.valid and est.source is PositionSource.GNSS
        if self._last_pose is None or reseed:
            std = (
                max(est.pos_std_m, _INIT_MIN_STD[0]),
                max(est.pos_std_m, _INIT_MIN_STD[1]),
                max(est.yaw_std_rad, _INIT_MIN_STD[2]),
            )
            self.filter.initialise((pose.x_m, pose.y_m, pose.yaw_rad), std)
            st.reseeds += reseed
            self._disagreements = 0
        else:
            delta = self._last_pose.inverse().compose(pose)
            self.filter.motion((delta.x_m, delta.y_m, delta.yaw_rad))
        self._last_pose = pose
        keep = ~np.asarray(result.noise, dtype=bool)
        ranges, angles = planar_scan(
            np.asarray(result.cloud.points[keep, :3]), 360, s.min_height_m, s.max_height_m
        )
        if not self.filter.scan(ranges, angles):
            return
        st.filter_updates += 1
        out = self.filter.estimate()
        # The filter's own `confident` looks at its worst axis; along a straight street the particles
        # spread along the road while the across-road position is sharp: the measurement below fuses
        # only the directions within max_direction_std_m, so the sharp one is not thrown away.
        if out.random_injection > s.max_random_injection:
            st.not_confident += 1
            self._disagreements += 1
            return
        m = ScanMatchMeasurement(
            stamp=result.cloud.stamp,
            x_m=out.x_m,
            y_m=out.y_m,
            yaw_rad=out.yaw_rad,
            covariance=out.covariance,
            max_direction_std_m=s.max_direction_std_m,
            max_yaw_std_rad=s.max_yaw_std_rad,
        )
        before = ekf.rejected_pose_measurements
        st.updates += ekf.update_pose(m, PositionSource.AMCL)
        rejected = ekf.rejected_pose_measurements - before
        st.gate_rejections += rejected
        self._disagreements = self._disagreements + 1 if rejected else 0

    def cpu_p50_ms(self) -> float | None:
        """Median CPU time per cloud, ms."""
        return float(np.median(self.stats.cpu_ms)) if self.stats.cpu_ms else None

    def counters(self) -> dict[str, int]:
        """The stack report's counters of this mode."""
        st = self.stats
        return {
            "amcl_clouds": st.clouds,
            "amcl_filter_updates": st.filter_updates,
            "amcl_updates": st.updates,
            "amcl_not_confident": st.not_confident,
            "amcl_gate_rejections": st.gate_rejections,
            "amcl_reseeds": st.reseeds,
        }
