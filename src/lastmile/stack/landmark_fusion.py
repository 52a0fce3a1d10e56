"""The ``landmarks`` localization mode's glue: the raw LiDAR chain's clusters in, pose corrections out.

Each rig frame the LiDAR chain has processed (its merged cloud in the base frame at the frame's stamp,
and the cluster label of every non-ground return) is searched for light poles and building facades
(:func:`lastmile.localization.landmark_extraction.extract_landmarks`); they are associated with the
s-layer's landmark records around the shuttle's route position and fused by the pose EKF at the
cloud's own stamp (``PoseEkf.update_pose``, which inserts a late measurement at its stamp). An accepted
correction makes the estimate's source LANDMARKS (:mod:`lastmile.localization.position_source`). Only
the map and the stack's own sensor data are used, never the simulator's truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from lastmile.hdmap.layers import SLayerDatabase
from lastmile.localization.ekf import PoseEkf
from lastmile.localization.landmark_extraction import LandmarkExtractionConfig, extract_landmarks
from lastmile.localization.landmark_localization import FacadeDetections, MapLandmarks, PoleDetections
from lastmile.perception.pipeline import LidarPipelineResult


@dataclass(slots=True)
class LandmarkFusionStats:
    """Counters for the run's report."""

    clouds: int = 0
    poles_detected: int = 0
    facades_detected: int = 0
    pole_updates: int = 0
    facade_updates: int = 0
    rejected: int = 0
    cpu_ms: list[float] = field(default_factory=list)
    """This thread's CPU time per fused cloud (reporting only: on a shared machine the wall time also
    counts the time other processes held the core)."""


class LandmarkFusion:
    """Poles and facades from the LiDAR chain's clouds into the pose EKF."""

    def __init__(self, config: LandmarkExtractionConfig, layers: SLayerDatabase) -> None:
        self.config = config
        self.layers = layers
        self.stats = LandmarkFusionStats()
        self._last_stamp_us: int | None = None

    def fuse(self, ekf: PoseEkf, result: LidarPipelineResult, route_s_m: float | None) -> None:
        """Fuse the landmarks of ``result``'s cloud once (a cloud already fused is skipped); nothing
        before the shuttle knows its route position."""
        stamp = result.cloud.stamp
        if self._last_stamp_us == int(stamp) or route_s_m is None:
            return
        self._last_stamp_us = int(stamp)
        start = time.thread_time()
        self._fuse(ekf, result, route_s_m)
        self.stats.cpu_ms.append((time.thread_time() - start) * 1e3)

    def _fuse(self, ekf: PoseEkf, result: LidarPipelineResult, route_s_m: float) -> None:
        stamp = result.cloud.stamp
        found = extract_landmarks(result.cloud.points[:, :3], result.labels, self.config)
        st = self.stats
        st.clouds += 1
        st.poles_detected += len(found.pole_xy_m)
        st.facades_detected += len(found.facade_lines)
        marks = MapLandmarks.near(self.layers, route_s_m)
        if len(found.pole_xy_m) and len(marks.poles):
            poles = PoleDetections(
                stamp=stamp,
                points_base=found.pole_xy_m,
                std_m=float(np.max(found.pole_std_m)),
                landmarks=marks,
                point_std_m=found.pole_std_m,
            )
            st.pole_updates += ekf.update_pose(poles)
        if len(found.facade_lines) and len(marks.segments):
            facades = FacadeDetections(
                stamp=stamp,
                lines_base=found.facade_lines,
                distance_std_m=float(np.max(found.facade_distance_std_m)),
                angle_std_rad=float(np.max(found.facade_angle_std_rad)),
                landmarks=marks,
                line_std=np.column_stack([found.facade_distance_std_m, found.facade_angle_std_rad]),
            )
            st.facade_updates += ekf.update_pose(facades)
        st.rejected = ekf.rejected_pose_measurements

    def cpu_p50_ms(self) -> float | None:
        """Median CPU time per fused cloud (extraction, association, EKF update), ms."""
        return float(np.median(self.stats.cpu_ms)) if self.stats.cpu_ms else None

    def counters(self) -> dict[str, int]:
        """The stack report's counters of this mode."""
        st = self.stats
        return {
            "landmark_clouds": st.clouds,
            "landmark_poles_detected": st.poles_detected,
            "landmark_facades_detected": st.facades_detected,
            "landmark_pole_updates": st.pole_updates,
            "landmark_facade_updates": st.facade_updates,
            "landmark_rejected_updates": st.rejected,
        }
