"""The LiDAR-only detection chain of WATonoBus on a multi-LiDAR rig, with per-stage timing.

compensation + merge -> crop (region of interest, ego body) -> ground -> weather noise filter ->
curbs (boundary + obstacle reassignment) -> clustering -> cluster geometry -> snow surface (low, bright
clusters on any mapped curb line are snow lying there, not objects; only with the map's curb lines).
The stage times (wall: ``time.perf_counter``, CPU: ``time.thread_time``) are for reporting only;
no result depends on them.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import DETECTION_COLUMNS, DetectedObjects
from lastmile.core.sensor_frames import LidarSweep
from lastmile.perception.cluster_geometry import ClusterGeometryConfig, ClusterSet, describe_cloud_clusters
from lastmile.perception.cluster_split import ClusterSplitConfig, split_pedestrians
from lastmile.perception.clustering import euclidean_cluster_labels, euclidean_cluster_rows
from lastmile.perception.curbs import CurbConfig, CurbEstimate, detect_curb
from lastmile.perception.deskew_kernel import crop_points
from lastmile.perception.ground import GROUND_SEGMENTERS, AdaptiveGridConfig, make_ground_segmenter
from lastmile.perception.himmelsbach import HimmelsbachConfig
from lastmile.perception.merge import MergedCloud, merged_points
from lastmile.perception.motion_compensation import PoseTrajectory
from lastmile.perception.road_region import RoadMask
from lastmile.perception.scan_density import return_weights, ring_spacing_from_points
from lastmile.perception.snow_surface import SnowSurfaceConfig, drop_clusters, snow_surface_clusters
from lastmile.perception.weather_filter import DrorConfig, azimuth_step_from_times, dror_keep_rows


@dataclass(frozen=True, slots=True, kw_only=True)
class CropConfig:
    """Region of interest and the ego body, base frame, metres.

    Attributes:
        x_min_m, x_max_m, half_width_m: kept box around the bus (behind, ahead, to each side).
        z_max_m: points above are dropped (GEM: points above the shuttle cannot hit it).
        ego_x_min_m, ego_x_max_m, ego_half_width_m: the bus body; returns inside are self-hits.
    """

    x_min_m: float = -30.0
    x_max_m: float = 60.0
    half_width_m: float = 30.0
    z_max_m: float = 4.0
    ego_x_min_m: float = -1.2
    ego_x_max_m: float = 4.6
    ego_half_width_m: float = 1.2

    def __post_init__(self) -> None:
        if not (self.x_min_m < self.x_max_m and self.half_width_m > 0 and self.z_max_m > 0):
            raise ConfigError(f"CropConfig: expected x_min_m < x_max_m and positive sizes, got {self}")
        if not (self.ego_x_min_m < self.ego_x_max_m and self.ego_half_width_m >= 0):
            raise ConfigError(f"CropConfig: expected ego_x_min_m < ego_x_max_m, got {self}")


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarPipelineConfig:
    """Attributes:
    ground: registry name of the ground segmenter ("adaptive_grid" or "himmelsbach").
    cluster_eps_m: Euclidean clustering link length (DBSCAN eps with min_samples = 1).
    weather_filter: run DROR after ground removal (off only for ablations).
    snow_surface: the snow-surface test of clusters (applied when curb lines are given).
    weight_by_unit_density: the cluster size filter counts each return by its LiDAR's angular
        cell (column x ring spacing) relative to the densest unit's (:mod:`scan_density`), so a
        sparse blind-spot unit's short row on a car end counts as the surface it covers.
    time_bin_us: de-skew time-bin width.
    split: pedestrians carved out of larger clusters (:mod:`cluster_split`).
    """

    ground: str = "adaptive_grid"
    adaptive_grid: AdaptiveGridConfig = field(default_factory=AdaptiveGridConfig)
    himmelsbach: HimmelsbachConfig = field(default_factory=HimmelsbachConfig)
    crop: CropConfig = field(default_factory=CropConfig)
    dror: DrorConfig = field(default_factory=DrorConfig)
    weather_filter: bool = True
    cluster_eps_m: float = 0.5
    geometry: ClusterGeometryConfig = field(default_factory=ClusterGeometryConfig)
    curb: CurbConfig = field(default_factory=CurbConfig)
    snow_surface: SnowSurfaceConfig = field(default_factory=SnowSurfaceConfig)
    weight_by_unit_density: bool = True
    time_bin_us: int = 500
    split: ClusterSplitConfig = field(default_factory=ClusterSplitConfig)

    def __post_init__(self) -> None:
        if self.ground not in GROUND_SEGMENTERS:
            raise ConfigError(
                f"LidarPipelineConfig.ground: expected one of {sorted(GROUND_SEGMENTERS)}, "
                f"got {self.ground!r}"
            )
        if not (math.isfinite(self.cluster_eps_m) and 0.05 <= self.cluster_eps_m <= 3.0):
            raise ConfigError(
                f"LidarPipelineConfig.cluster_eps_m: expected 0.05..3 m, got {self.cluster_eps_m}"
            )
        if self.time_bin_us <= 0:
            raise ConfigError(f"LidarPipelineConfig.time_bin_us: expected > 0, got {self.time_bin_us}")


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarPipelineResult:
    """Everything one rig frame produced.

    Attributes:
        cloud: the merged cloud after cropping (base frame at ``cloud.stamp``).
        source_index: (N,) int64 row of each cloud point in the concatenation of the input sweeps
            (in the order given), so per-point ground truth can be matched in evaluation.
        ground: (N,) bool ground points of ``cloud``.
        noise: (N,) bool points removed by the weather filter.
        labels: (N,) int64 cluster label, -1 for ground and noise.
        clusters: clusters that passed the size filter (see :class:`ClusterSet`).
        curb: the curb estimate (None when no map curb was given).
        curb_obstacle: (N,) bool points the curb step reassigned as obstacles.
        curb_surface: (N,) bool non-ground points the curb step found to be the curb, sidewalk
            edge or snow bank on the curb side of the boundary (not clustered).
        snow_surface: (N,) bool points of clusters found to be snow lying along a mapped curb
            (:mod:`lastmile.perception.snow_surface`; not in ``clusters``, labels kept).
        stage_ms: wall time per stage, milliseconds (reporting only).
        stage_cpu_ms: this thread's CPU time per stage, milliseconds (reporting only: on a shared
            machine the wall time also counts the time other processes held the core).
    """

    cloud: MergedCloud
    source_index: np.ndarray
    ground: np.ndarray
    noise: np.ndarray
    labels: np.ndarray
    clusters: ClusterSet
    curb: CurbEstimate | None
    curb_obstacle: np.ndarray
    stage_ms: dict[str, float]
    curb_surface: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    snow_surface: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    stage_cpu_ms: dict[str, float] = field(default_factory=dict)

    def detected_objects(self, min_confidence: float = 0.0) -> DetectedObjects:
        """Clusters as :class:`DetectedObjects` in the base frame, class UNKNOWN, velocity 0."""
        t = self.clusters.table
        n = len(t)
        table = np.zeros((n, len(DETECTION_COLUMNS)))
        table[:, 0] = self.clusters.col("x_m")
        table[:, 1] = self.clusters.col("y_m")
        table[:, 4] = np.maximum(self.clusters.col("length_m"), 0.1)
        table[:, 5] = np.maximum(self.clusters.col("width_m"), 0.1)
        table[:, 6] = self.clusters.col("yaw_rad")
        table[:, 7] = int(ObjectClass.UNKNOWN)
        table[:, 8] = np.maximum(self.clusters.col("confidence"), 0.5)
        keep = table[:, 8] >= min_confidence
        return DetectedObjects(stamp=self.cloud.stamp, frame="base", source="lidar", table=table[keep])


class LidarPipeline:
    """Runs the LiDAR chain on one rig frame; built once with its configuration."""

    def __init__(self, config: LidarPipelineConfig | None = None) -> None:
        self.config = config or LidarPipelineConfig()
        cfg = self.config
        self.ground_segmenter = make_ground_segmenter(
            cfg.ground, cfg.adaptive_grid if cfg.ground == "adaptive_grid" else cfg.himmelsbach
        )

    def process(
        self,
        sweeps: Sequence[LidarSweep],
        base_from_sensor: Mapping[str, npt.ArrayLike],
        trajectory: PoseTrajectory | None = None,
        road_mask: RoadMask | None = None,
        map_curb_xy_m: npt.ArrayLike | None = None,
        curb_lines_xy_m: Sequence[npt.ArrayLike] | None = None,
    ) -> LidarPipelineResult:
        """One rig frame.

        Args:
            sweeps: one sweep per LiDAR.
            base_from_sensor: (4, 4) extrinsics per sensor id.
            trajectory: INS poses covering the sweeps (None: no de-skew, e.g. a parked bus).
            road_mask: HD-map road region for the adaptive grid (None: all road).
            map_curb_xy_m: (M, 2) the map's right curb in the base frame (None: no curb step).
            curb_lines_xy_m: every mapped curb line near the vehicle, each (M, 2) in the base frame,
                any side (None: no snow-surface test; low bright clusters stay objects).
        """
        cfg = self.config
        clock = _StageClock()
        # The merged points stay the pipeline's own array: only the cropped cloud is kept (and
        # checked and frozen as a MergedCloud).
        stamp, pts = merged_points(sweeps, base_from_sensor, trajectory, time_bin_us=cfg.time_bin_us)
        clock.lap("compensate_merge")
        c = cfg.crop
        # One compiled pass: the rows inside the region and outside the ego body, and the kept
        # coordinates in float64 (every stage computes in float64 and would otherwise copy).
        source_index, kept, xyz = crop_points(
            pts,
            np.array([c.x_min_m, c.x_max_m, c.half_width_m, c.z_max_m], dtype=np.float32),
            np.array([c.ego_x_min_m, c.ego_x_max_m, c.ego_half_width_m], dtype=np.float32),
        )
        cloud = MergedCloud(
            stamp=stamp,
            points=kept,
            sensor_ids=tuple(s.sensor_id for s in sweeps),
            compensated=trajectory is not None,
        )
        clock.lap("crop")
        ground = self.ground_segmenter.segment(xyz, road_mask)
        clock.lap("ground")
        ng = np.flatnonzero(~ground)
        noise = np.zeros(len(xyz), dtype=bool)
        # Each unit's column spacing, read from its sweep's firing times (DROR's radius and the
        # weight of its returns in the cluster size filter).
        sweep_of = {s.sensor_id: s for s in sweeps}
        steps = np.array([azimuth_step_from_times(sweep_of[sid].points[:, 5]) for sid in cloud.sensor_ids])
        if cfg.weather_filter and len(ng):
            # Each point ranged from its own LiDAR, with that unit's column step; the scan key
            # and grid from its sensor index and ring (gathered in one compiled pass).
            keep = dror_keep_rows(xyz, cloud.points, ng, _sensor_xy(cloud, base_from_sensor), steps, cfg.dror)
            noise[ng[~keep]] = True
            ng = ng[keep]
        clock.lap("weather_filter")
        # Curbs first: the boundary decides which raised points near it are curb, sidewalk edge or
        # snow bank (not objects) and which ground points on the road side are obstacles.
        curb = None
        curb_obstacle = np.zeros(len(xyz), dtype=bool)
        curb_surface = np.zeros(len(xyz), dtype=bool)
        if map_curb_xy_m is not None:
            curb = detect_curb(xyz, map_curb_xy_m, cfg.curb)
            curb_obstacle[curb.obstacle_idx] = True
            curb_surface[curb.surface_idx] = True
        clock.lap("curbs")
        labels = np.full(len(xyz), -1, dtype=np.int64)
        # Without a curb estimate no point is curb surface or reassigned (the masks are empty).
        objects = ng if curb is None else ng[~curb_surface[ng]]
        labels[objects] = euclidean_cluster_rows(xyz, objects, cfg.cluster_eps_m)
        if curb is not None:
            # Reassigned points the ground step had taken become obstacle points of their own.
            newly = np.flatnonzero(curb_obstacle & (labels < 0) & ~noise)
            if len(newly):
                extra = euclidean_cluster_labels(xyz[newly], cfg.cluster_eps_m)
                labels[newly] = extra + (labels.max() + 1)
        if cfg.split.enabled:
            labels = split_pedestrians(xyz, labels, ground, cfg.split)
        clock.lap("clustering")
        unit_weight = None
        if cfg.weight_by_unit_density:
            spacing = [ring_spacing_from_points(sweep_of[sid].points) for sid in cloud.sensor_ids]
            unit_weight = return_weights(np.maximum(steps, cfg.dror.azimuth_step_rad), spacing)
        # The labelled points read in place (no gather of them first).
        clusters = describe_cloud_clusters(xyz, cloud.points, labels, unit_weight, cfg.geometry)
        clock.lap("cluster_geometry")
        snow_surface = np.zeros(len(xyz), dtype=bool)
        if curb_lines_xy_m is not None:
            snow = snow_surface_clusters(clusters, curb_lines_xy_m, cfg.snow_surface)
            if snow.any():
                snow_surface = np.isin(labels, clusters.labels[snow])
                clusters = drop_clusters(clusters, snow)
        clock.lap("snow_surface")
        clock.finish()
        return LidarPipelineResult(
            cloud=cloud,
            source_index=source_index,
            ground=ground,
            noise=noise,
            labels=labels,
            clusters=clusters,
            curb=curb,
            curb_obstacle=curb_obstacle,
            stage_ms=clock.wall_ms,
            stage_cpu_ms=clock.cpu_ms,
            curb_surface=curb_surface,
            snow_surface=snow_surface,
        )


class _StageClock:
    """Wall and thread-CPU milliseconds per stage, and their totals (reporting only)."""

    def __init__(self) -> None:
        self.wall_ms: dict[str, float] = {}
        self.cpu_ms: dict[str, float] = {}
        self._wall0 = self._wall = time.perf_counter()
        self._cpu0 = self._cpu = time.thread_time()

    def lap(self, stage: str) -> None:
        wall, cpu = time.perf_counter(), time.thread_time()
        self.wall_ms[stage] = (wall - self._wall) * 1e3
        self.cpu_ms[stage] = (cpu - self._cpu) * 1e3
        self._wall, self._cpu = wall, cpu

    def finish(self) -> None:
        self.wall_ms["total"] = (self._wall - self._wall0) * 1e3
        self.cpu_ms["total"] = (self._cpu - self._cpu0) * 1e3


def _sensor_xy(cloud: MergedCloud, base_from_sensor: Mapping[str, npt.ArrayLike]) -> np.ndarray:
    """(S, 2) horizontal position of each LiDAR of the cloud, by sensor index (DROR ranges from it)."""
    return np.array([np.asarray(base_from_sensor[s], dtype=np.float64)[:2, 3] for s in cloud.sensor_ids])
