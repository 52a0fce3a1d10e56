"""The ``scan_matching`` localization mode's glue: the raw LiDAR chain's clouds in, pose corrections out.

Each rig frame the LiDAR chain has processed (its merged, motion-compensated cloud in the base frame at
the frame's stamp, the weather filter's noise removed) is registered to the point-cloud map
(:class:`lastmile.localization.scan_matching.ScanToMapMatcher`) starting at the inertial EKF's pose at
that stamp, checked (:func:`lastmile.localization.scan_match_localization.measurement`) and fused by the
EKF at the cloud's own stamp (``PoseEkf.update_pose``: a late measurement is inserted at its stamp,
gated by its Mahalanobis distance). An accepted correction makes the estimate's source SCAN_MATCHING.
Only the map and the stack's own sensor data are used, never the simulator's truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import MessageError
from lastmile.core.vehicle_messages import PositionSource
from lastmile.localization.ekf import PoseEkf
from lastmile.localization.map_build import planar_matrix
from lastmile.localization.scan_match_localization import ScanMatchingSettings, measurement
from lastmile.localization.scan_matching import ScanToMapMatcher
from lastmile.perception.pipeline import LidarPipelineResult


@dataclass(slots=True)
class ScanMatchStats:
    """Counters for the run's report."""

    clouds: int = 0
    updates: int = 0
    poor_matches: int = 0
    """Not converged, too few points paired, RMSE over the limit, or too few points in range."""
    degenerate: int = 0
    """Matches fused along fewer than all three of x, y, yaw (a direction the scene does not constrain)."""
    gate_rejections: int = 0
    cpu_ms: list[float] = field(default_factory=list)
    """This thread's CPU time per cloud (registration and EKF update; reporting only)."""


class ScanMatchFusion:
    """Scans from the LiDAR chain registered to the map, into the pose EKF."""

    def __init__(self, settings: ScanMatchingSettings, map_points: np.ndarray | None = None) -> None:
        self.settings = settings
        points = settings.load_map() if map_points is None else map_points
        self.matcher = ScanToMapMatcher(points, settings.matcher)
        self.stats = ScanMatchStats()
        self._last_stamp_us: int | None = None

    def fuse(self, ekf: PoseEkf, result: LidarPipelineResult) -> None:
        """Register and fuse ``result``'s cloud once (a cloud already fused is skipped); nothing before
        the filter has a position and heading."""
        stamp = result.cloud.stamp
        if self._last_stamp_us == int(stamp) or not ekf.initialised:
            return
        self._last_stamp_us = int(stamp)
        start = time.thread_time()
        self._fuse(ekf, result)
        self.stats.cpu_ms.append((time.thread_time() - start) * 1e3)

    def _fuse(self, ekf: PoseEkf, result: LidarPipelineResult) -> None:
        st = self.stats
        st.clouds += 1
        stamp = result.cloud.stamp
        est = ekf.estimate(stamp)
        pose = est.map_from_base
        keep = ~np.asarray(result.noise, dtype=bool)
        points = np.asarray(result.cloud.points[keep, :3], dtype=np.float64)
        try:
            match = self.matcher.match(points, planar_matrix(pose.x_m, pose.y_m, pose.yaw_rad))
        except MessageError:  # fewer than 30 points in range: a blinded rig has nothing to match
            st.poor_matches += 1
            return
        m = measurement(match, stamp, self.settings)
        if m is None:
            st.poor_matches += 1
            return
        st.degenerate += m.rows().shape[0] < 3
        before = ekf.rejected_pose_measurements
        st.updates += ekf.update_pose(m, PositionSource.SCAN_MATCHING)
        st.gate_rejections += ekf.rejected_pose_measurements - before

    def cpu_p50_ms(self) -> float | None:
        """Median CPU time per cloud (registration, checks, EKF update), ms."""
        return float(np.median(self.stats.cpu_ms)) if self.stats.cpu_ms else None

    def counters(self) -> dict[str, int]:
        """The stack report's counters of this mode."""
        st = self.stats
        return {
            "scan_match_clouds": st.clouds,
            "scan_match_updates": st.updates,
            "scan_match_poor": st.poor_matches,
            "scan_match_degenerate": st.degenerate,
            "scan_match_gate_rejections": st.gate_rejections,
        }
