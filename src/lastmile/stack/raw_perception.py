"""Raw-sensor perception in the stack: LiDAR sweeps, radar objects and camera boxes in, tracks out.

Per revolution of the LiDAR rig (one sweep of every unit, stamped alike):

1. de-skew with the localization's own pose history (``PoseEkf.estimate`` at the sweep's times),
   merge, ground, weather filter, clustering and curbs (:class:`perception.LidarPipeline`), with the
   HD map's road region, the map's right curb along the route and every mapped curb line within
   ``curb_lines_reach_m`` as priors (the pipeline's curb-side stage: clusters that are low and lie
   on a curb line are the curb face, low, flat, bright ones beside one snow lying along the curb,
   not objects; :mod:`lastmile.perception.snow_surface`);
   With a learned LiDAR detector configured (``RawPerceptionConfig.detector``, an ONNX model,
   :mod:`lastmile.perception.lidar_detector`), its boxes, classes and scores replace the clusters
   they cover; the other clusters stay unclassified objects (or, with ``merge = "replace_clusters"``,
   the detections alone go on);
2. WATonoBus late fusion (:func:`perception.late_fusion.fuse_objects`): the newest radar frames,
   brought to the cloud's instant through the pose history, give velocities; the newest camera boxes
   give classes;
3. aUToTrack (:class:`tracking.autotrack.AutoTrack`) in the map frame, with radar Doppler where fused;
4. published tracks: scenery is left out. A track off the road surface that no camera called a road
   user and that does not move is a pole, a wall or a hedge: decision making would otherwise yield to
   it at every crosswalk. On the road surface every track stays (a goose, a fallen barrel).

A rig frame is processed when every LiDAR's sweep of that revolution has arrived, or after
``set_timeout_us`` with what did (a dead unit must not blind the others; the reliability monitor
reports the unit).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.boxes3d import DetectedBoxes
from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, DetectedObjects, TrackedObjects
from lastmile.core.sensor_frames import CameraDetections, LidarSweep, RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.hdmap.drivable import DrivableRaster
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.localization.ekf import LocalizationEstimate
from lastmile.perception.late_fusion import LateFusionConfig, fuse_objects
from lastmile.perception.lidar_detector import (
    LidarDetectorConfig,
    MergedObjects,
    OnnxLidarDetector,
    frame_objects,
)
from lastmile.perception.map_curbs import MapCurbIndex
from lastmile.perception.motion_compensation import PoseTrajectory
from lastmile.perception.pipeline import LidarPipeline, LidarPipelineConfig, LidarPipelineResult
from lastmile.perception.road_region import MapRoadRegion
from lastmile.tracking.autotrack import AutoTrack, AutoTrackConfig, ClassParams, default_class_params

PoseSource = Callable[[Stamp], LocalizationEstimate]
"""The localization's pose at a stamp (past ones from its history)."""


def stack_tracker_config() -> AutoTrackConfig:
    """aUToTrack for 10 Hz LiDAR clusters: unclassified and small objects coast through a few misses.

    A goose at 30 m gives 3-5 returns and is missed in some sweeps; with the KITTI defaults an
    unclassified track was demoted at its first miss and the goose blinked in and out of the plan.
    """
    classes = dict(default_class_params())
    classes[ObjectClass.UNKNOWN] = ClassParams(gate_m=2.5, t_birth_s=0.15, t_expire_s=0.35, t_prune_s=0.6)
    classes[ObjectClass.ANIMAL] = ClassParams(
        gate_m=2.0, accel_std_mps2=3.0, pos_std_m=0.2, yaw_std_rad=0.8, t_expire_s=0.35, t_prune_s=0.6
    )
    return AutoTrackConfig(classes=classes)


@dataclass(frozen=True, slots=True, kw_only=True)
class RawPerceptionConfig:
    """Attributes:
    pipeline: the LiDAR chain.
    fusion: radar and camera association.
    tracker: aUToTrack.
    set_timeout_us: a rig frame missing a unit's sweep is processed this long after its first sweep.
    pose_step_us: spacing of the poses the de-skew interpolates.
    radar_max_age_us, camera_max_age_us: older radar frames / camera boxes are not fused.
    curb_behind_m, curb_ahead_m: stretch of the map's right curb (along the route) given as prior.
    curb_vertex_step_m: vertex spacing of that prior (the curb search costs O(points x vertices)).
    curb_lines_reach_m: mapped curb lines (any side) within this of the shuttle are given to the
        pipeline's curb-side stage (the LiDAR crop reaches 30 m to the side, 60 m ahead).
    scenery_speed_mps: an off-road, unclassified track slower than this is scenery (not published).
    scenery_min_age_s: ...once it is this old (a new track's velocity is not yet known).
    detector: a learned LiDAR detector (ONNX) whose boxes join the clusters (None: clusters only).
    """

    pipeline: LidarPipelineConfig = field(default_factory=LidarPipelineConfig)
    fusion: LateFusionConfig = field(default_factory=LateFusionConfig)
    tracker: AutoTrackConfig = field(default_factory=stack_tracker_config)
    set_timeout_us: int = 60_000
    pose_step_us: int = 10_000
    radar_max_age_us: int = 150_000
    camera_max_age_us: int = 200_000
    curb_behind_m: float = 5.0
    curb_ahead_m: float = 35.0
    curb_vertex_step_m: float = 2.5
    curb_lines_reach_m: float = 45.0
    scenery_speed_mps: float = 0.5
    scenery_min_age_s: float = 0.5
    detector: LidarDetectorConfig | None = None

    def __post_init__(self) -> None:
        for name in ("set_timeout_us", "pose_step_us", "radar_max_age_us", "camera_max_age_us"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"RawPerceptionConfig.{name}: expected > 0, got {getattr(self, name)}")
        if not (math.isfinite(self.curb_vertex_step_m) and 0.1 <= self.curb_vertex_step_m <= 10.0):
            raise ConfigError(
                f"RawPerceptionConfig.curb_vertex_step_m: expected 0.1..10 m, got {self.curb_vertex_step_m}"
            )
        for name in (
            "curb_behind_m",
            "curb_ahead_m",
            "scenery_speed_mps",
            "scenery_min_age_s",
            "curb_lines_reach_m",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ConfigError(f"RawPerceptionConfig.{name}: expected a finite value >= 0, got {v}")


@dataclass(slots=True)
class RawPerceptionStats:
    """Counters for the run's report."""

    rig_frames: int = 0
    incomplete_frames: int = 0
    skipped_no_pose: int = 0
    curb_valid: int = 0
    curb_offsets_m: list[float] = field(default_factory=list)
    clusters: int = 0
    curb_returns: int = 0
    scenery_tracks_hidden: int = 0
    detections: int = 0
    clusters_replaced: int = 0


class RawPerception:
    """LiDAR + radar + camera perception and tracking, fed frame by frame.

    Args:
        config: parameters.
        layers: the route's s-layers (road region and right curb come from its map).
        lidar_mounts: (4, 4) base_from_sensor per LiDAR id (calibration).
        cameras: the cameras (calibration), matched to detections by id.
        radar_mounts: base_from_sensor per radar id.
    """

    def __init__(
        self,
        config: RawPerceptionConfig,
        layers: SLayerDatabase,
        lidar_mounts: Mapping[str, np.ndarray],
        cameras: Sequence[PinholeCamera],
        radar_mounts: Mapping[str, SE2],
    ) -> None:
        if not lidar_mounts:
            raise ConfigError("RawPerception: expected at least one LiDAR mounting, got none")
        self.config = config
        self.layers = layers
        self.lidar_mounts = {k: np.asarray(v, dtype=np.float64) for k, v in lidar_mounts.items()}
        for k, v in self.lidar_mounts.items():
            if v.shape != (4, 4) or not np.isfinite(v).all():
                raise ConfigError(
                    f"RawPerception: LiDAR {k!r} mounting: expected a finite (4, 4), got {v.shape}"
                )
        self.cameras = tuple(cameras)
        self.radar_mounts = dict(radar_mounts)
        self.pipeline = LidarPipeline(config.pipeline)
        self.road = MapRoadRegion(layers.hdmap)
        self.curbs = MapCurbIndex(layers.hdmap)
        self.tracker = AutoTrack(config.tracker)
        self.detector = OnnxLidarDetector(config.detector) if config.detector is not None else None
        self.stats = RawPerceptionStats()
        self.last_result: LidarPipelineResult | None = None
        self._detections: list[DetectedObjects] = []
        self._sets: dict[int, dict[str, LidarSweep]] = {}
        self._set_first_seen_us: dict[int, int] = {}
        self._radar: dict[str, RadarFrame] = {}
        self._camera: dict[str, CameraDetections] = {}

    @property
    def pending(self) -> bool:
        """A rig frame is waiting (complete or not yet timed out)."""
        return bool(self._sets)

    # ------------------------------------------------------------------------------------------------
    def on_frame(self, frame: LidarSweep | RadarFrame | CameraDetections, now: Stamp) -> None:
        """Keep a frame until its rig frame is processed (LiDAR) or a newer one replaces it."""
        if isinstance(frame, LidarSweep):
            if frame.sensor_id not in self.lidar_mounts:
                raise MessageError(
                    f"RawPerception: expected a sweep from a calibrated LiDAR {sorted(self.lidar_mounts)}, "
                    f"got {frame.sensor_id!r}"
                )
            key = int(frame.stamp)
            self._sets.setdefault(key, {})[frame.sensor_id] = frame
            self._set_first_seen_us.setdefault(key, int(now))
        elif isinstance(frame, RadarFrame):
            old = self._radar.get(frame.sensor_id)
            if old is None or frame.stamp >= old.stamp:
                self._radar[frame.sensor_id] = frame
        else:
            old_c = self._camera.get(frame.camera_id)
            if old_c is None or frame.stamp >= old_c.stamp:
                self._camera[frame.camera_id] = frame

    def step(self, now: Stamp, pose_at: PoseSource, route_s_m: float | None) -> int:
        """Process every rig frame that is complete (or timed out); returns how many."""
        done = 0
        for key in sorted(self._sets):
            sweeps = self._sets[key]
            complete = len(sweeps) == len(self.lidar_mounts)
            if not complete and int(now) - self._set_first_seen_us[key] < self.config.set_timeout_us:
                continue
            del self._sets[key]
            del self._set_first_seen_us[key]
            if not complete:
                self.stats.incomplete_frames += 1
            self._process([sweeps[k] for k in sorted(sweeps)], pose_at, route_s_m)
            done += 1
        return done

    def drain_detections(self) -> tuple[DetectedObjects, ...]:
        """The fused detections given to the tracker since the last call (map frame), oldest first."""
        out, self._detections = tuple(self._detections), []
        return out

    def tracks(self, now: Stamp) -> TrackedObjects:
        """Published tracks at ``now``, map frame (scenery left out)."""
        tb = self.tracker.tracks(now)
        n = len(tb)
        if n == 0:
            return TrackedObjects(
                stamp=now, ids=np.zeros(0, np.int64), table=np.zeros((0, len(TRACK_COLUMNS)))
            )
        t = tb.table
        table = np.column_stack(
            [t[:, 0], t[:, 1], t[:, 7], t[:, 8], t[:, 3], t[:, 4], t[:, 6], tb.class_id, t[:, 10], t[:, 11]]
        )
        on_road = self.road.raster.classify(t[:, 0:2]) != DrivableRaster.OUTSIDE
        road_user = tb.class_id != int(ObjectClass.UNKNOWN)
        moving = (np.hypot(t[:, 7], t[:, 8]) > self.config.scenery_speed_mps) | (
            t[:, 11] < self.config.scenery_min_age_s
        )
        keep = on_road | road_user | moving
        self.stats.scenery_tracks_hidden += int((~keep).sum())
        return TrackedObjects(stamp=now, ids=tb.ids[keep], table=table[keep])

    # ------------------------------------------------------------------------------------------------
    def _process(self, sweeps: list[LidarSweep], pose_at: PoseSource, route_s_m: float | None) -> None:
        start = min(int(s.stamp) for s in sweeps)
        end = max(int(s.stamp) + int(s.points[:, 5].max(initial=0.0)) for s in sweeps)
        step = self.config.pose_step_us
        times = np.arange(start - step, end + 2 * step, step, dtype=np.int64)
        poses = [pose_at(Stamp(int(t))) for t in times]
        if not all(p.valid for p in poses):
            # No trustworthy pose: a cloud placed with a wrong pose is worse than none, and the
            # localization's failure is already the safety monitor's business.
            self.stats.skipped_no_pose += 1
            return
        yaw = np.unwrap([p.map_from_base.yaw_rad for p in poses])
        half = yaw / 2.0
        trajectory = PoseTrajectory(
            stamps_us=times,
            xyz_m=np.array([[p.map_from_base.x_m, p.map_from_base.y_m, 0.0] for p in poses]),
            quat_xyzw=np.column_stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)]),
        )
        # The merged cloud is expressed in the base frame at the newest sweep end.
        ref = Stamp(end)
        map_from_base = pose_at(ref).map_from_base
        result = self.pipeline.process(
            sweeps,
            self.lidar_mounts,
            trajectory,
            self.road.mask_for(map_from_base),
            self._map_curb_in_base(map_from_base, route_s_m),
            self.curbs.lines_near(map_from_base, self.config.curb_lines_reach_m),
        )
        self.last_result = result
        self.stats.rig_frames += 1
        self.stats.clusters += len(result.clusters.table)
        self.stats.curb_returns += len(np.unique(result.labels[result.snow_surface]))
        if result.curb is not None and result.curb.valid:
            self.stats.curb_valid += 1
            self.stats.curb_offsets_m.append(float(np.median(result.curb.offset_m)))
        base_inv = map_from_base.inverse()
        radar = [
            f for f in self._radar.values() if 0 <= int(ref) - int(f.stamp) <= self.config.radar_max_age_us
        ]
        # Each radar frame is placed where the shuttle was when it was captured.
        mounts = {
            f.sensor_id: base_inv.compose(pose_at(f.stamp).map_from_base).compose(
                self.radar_mounts[f.sensor_id]
            )
            for f in radar
            if f.sensor_id in self.radar_mounts
        }
        radar = [f for f in radar if f.sensor_id in mounts]
        cams = [
            d for d in self._camera.values() if abs(int(ref) - int(d.stamp)) <= self.config.camera_max_age_us
        ]
        objects = self._objects(result)
        fused = fuse_objects(
            ref,
            objects.clusters,
            radar,
            mounts,
            self.cameras,
            cams,
            map_from_base,
            self.config.fusion,
            lidar_class_id=objects.class_id,
            lidar_score=objects.score,
        )
        self._detections.append(fused.objects)
        o = fused.objects.table
        z_lo, z_hi = fused.z_min_m, fused.z_max_m
        height = np.maximum(z_hi - z_lo, 0.1)
        boxes = np.column_stack([o[:, 0], o[:, 1], (z_lo + z_hi) / 2.0, o[:, 4], o[:, 5], height, o[:, 6]])
        self.tracker.update(
            DetectedBoxes(
                stamp=ref,
                frame="map",
                source="lidar_fusion",
                boxes=boxes,
                class_id=o[:, 7].astype(np.int64),
                score=o[:, 8],
                velocity_mps=o[:, 2:4],
                has_velocity=fused.radar_matched,
                attributes=np.zeros((len(o), 0)),
            )
        )

    def _objects(self, result: LidarPipelineResult) -> MergedObjects:
        """The clusters, with the learned detector's boxes merged in when one is configured."""
        merged, detections = frame_objects(result, self.detector)
        self.stats.detections += detections
        self.stats.clusters_replaced += merged.replaced_clusters
        return merged

    def _map_curb_in_base(self, map_from_base: SE2, route_s_m: float | None) -> np.ndarray | None:
        """The map's right curb near the shuttle in the base frame; None where the route has none."""
        if route_s_m is None:
            return None
        L = self.layers
        c = self.config
        s = np.arange(route_s_m - c.curb_behind_m, route_s_m + c.curb_ahead_m, c.curb_vertex_step_m)
        d = L.curb_right_d_m[L.record_indices(s)]
        # The curb stretch that starts at the shuttle: an opening (junction, driveway) ends it.
        finite = np.isfinite(d)
        if not finite.all():
            stop = int(np.argmin(finite))
            s, d = s[:stop], d[:stop]
        if len(s) < 5:
            return None
        route = L.centerline
        xy = route.points_at(s)
        heading = np.array([route.heading_at(float(v)) for v in s])
        normal = np.column_stack([-np.sin(heading), np.cos(heading)])
        curb_map = xy + d[:, None] * normal
        return map_from_base.inverse().apply_points(curb_map)
