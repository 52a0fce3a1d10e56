"""The shuttle's software, wired: localization, perception and tracking, decision, planning, control.

It sees only sensor frames, the map and its own configuration (import-linter keeps ``sim`` out).
Modules run at integer divisors of the base tick: planning and decision at 10 Hz, control at 50 Hz,
estimation whenever a frame arrives, LiDAR perception whenever a rig frame is complete.

Perception modes (``StackConfig.perception_mode``, a :class:`~lastmile.core.perception_mode.PerceptionMode`):
LIDAR_CAMERA_RADAR runs the raw-sensor chain of :mod:`lastmile.stack.raw_perception` (LiDAR clusters
fused with radar and camera, aUToTrack); RADAR_TRACKING tracks the radars' object lists alone (cheaper:
the safety sweeps use it).

Safety is not in here: the vehicle's safety (:class:`lastmile.safety.vehicle_safety.VehicleSafety`,
built beside the stack by :mod:`lastmile.stack.vehicle_build`) runs in the loop, apart from the stack.
The stack reports its modules' heartbeats and its diagnostics, and obeys the directive it is handed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lastmile.control.gem_twist_longitudinal import GemTwistLongitudinalController
from lastmile.control.lateral import LateralConfig, LateralControllerName, make_lateral_controller
from lastmile.control.longitudinal import LongitudinalConfig, make_longitudinal_controller, stopping_gap_m
from lastmile.control.path_errors import path_ahead_of
from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2, FloatArray
from lastmile.core.objects import DetectedObjects, TrackedObjects, empty_tracks
from lastmile.core.pedal_map import gem_brake_pedal
from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.polyline import Polyline
from lastmile.core.predictions import PredictedPaths
from lastmile.core.route_obstacles import RouteObstacle, route_obstacles
from lastmile.core.safety_messages import SafetyDirective
from lastmile.core.sensor_frames import (
    CameraDetections,
    CrossingPresenceFrame,
    DoorSensorFrame,
    DropOffRequestFrame,
    GnssInsFrame,
    ImuFrame,
    LidarSweep,
    RadarFrame,
    SensorFrame,
    StopCallFrame,
    WheelOdometryFrame,
)
from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import TrafficLightDetections
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import (
    ActuatorCommand,
    BehaviourDecision,
    BehaviourState,
    HmiMessage,
    StackDiagnostics,
    StackOutput,
    StopReason,
    Trajectory,
    VehicleReport,
    VehicleStatus,
)
from lastmile.decision.behaviour_fsm import BehaviourStateMachine
from lastmile.decision.decision_config import DecisionConfig, DecisionInput
from lastmile.decision.mission import MissionManager
from lastmile.decision.turn_signal import TurnSignalRule
from lastmile.hdmap.corner_rounding import max_curvature_per_m
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.localization.amcl_localization import AmclSettings
from lastmile.localization.ekf import PoseEkf
from lastmile.localization.ekf_config import PoseEkfConfig
from lastmile.localization.landmark_extraction import LandmarkExtractionConfig
from lastmile.localization.odometry_ekf import OdometryEkf, OdometryEkfConfig, zero_slip_offset_m
from lastmile.localization.scan_match_localization import ScanMatchingSettings
from lastmile.perception.late_fusion import radar_detections
from lastmile.planning.local_path import LocalPathConfig
from lastmile.planning.planners import PASSING_PLANNERS, PlannerInputs, PlannerName, make_path_planner
from lastmile.planning.road_edge import rear_steers
from lastmile.planning.speed_planning import (
    SpeedInput,
    SpeedPlannerName,
    SpeedPlanningConfig,
    StQpSpeedPlanning,
    terminal_gap_m,
)
from lastmile.safety.reliability_config import ReliabilityConfig, default_sensor_specs
from lastmile.stack.amcl_fusion import AmclFusion
from lastmile.stack.gem_sign_stop import GemSignStop, GemSignStopSettings
from lastmile.stack.hmi import HmiComposer
from lastmile.stack.landmark_fusion import LandmarkFusion
from lastmile.stack.module_guard import ModuleGuard
from lastmile.stack.nus_speed_cap import NusSpeedCap, NusSpeedSettings
from lastmile.stack.occupancy_stop import OccupancyStop, OccupancyStopSettings
from lastmile.stack.profiler import ModuleProfiler
from lastmile.stack.raw_perception import RawPerception, RawPerceptionConfig
from lastmile.stack.scan_match_fusion import ScanMatchFusion
from lastmile.stack.stack_settings import LocalizationMode, check_localization_inputs
from lastmile.stack.v2i import AnticipationConfig, CrossingAnticipation
from lastmile.tracking.prediction import MapAwarePredictor, PredictionConfig
from lastmile.tracking.radar_tracker import RadarObjectTracker, RadarTrackerConfig
from lastmile.tracking.traffic_lights import TrafficLightTracker, TrafficLightTrackerConfig

DEFAULT_SENSORS = default_sensor_specs(radar_keys=("front", "rear"))
"""The simulator's sensor suite as the reliability monitor watches it (radars by their sensor ids)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class StackConfig:
    """The stack's own configuration (never the simulator's).

    Attributes:
        tick_us: base tick of the loop that calls ``tick``.
        planning_period_ticks, control_period_ticks: module rates as multiples of the tick.
        lateral_controller, longitudinal_controller: names in the registries of ``lastmile.control``.
        radar_mounts: base_from_sensor pose of each radar by sensor id.
        serve_all_stops: timetable mode (serve every stop) instead of on request.
        v2i: anticipation of crossings reported occupied by infrastructure cameras (``stack.v2i``).
        perception_mode: what the stack perceives through.
        lidar_mounts: (4, 4) base_from_sensor of each LiDAR by sensor id (raw perception).
        cameras: the cameras' calibration (raw perception).
        raw_perception: the raw-sensor chain's parameters.
        light_cameras: calibration of the cameras whose traffic-light detections the stack receives
            (none: the stack cannot see signals, and treats every mapped one it reaches as red).
        traffic_lights: the traffic-light tracker's parameters.
        prediction: map-aware prediction of the tracks (Snow Lion's constant velocity, lanes and
            crosswalks), handed to decision; its horizon must cover the decision's crosswalk and
            vehicle look-aheads.
        occupancy_stop: GEM's height-map obstacle stop (raw perception; None: off).
        nus_speed: NUS's speed rule over its cost map (raw perception; None: off).
        gem_sign_stop: GEM's LiDAR sign detector as a stop (raw perception; None: off).
    """

    tick_us: int = 10_000
    planning_period_ticks: int = 10
    control_period_ticks: int = 2
    lateral_controller: str = "heading_pid"
    longitudinal_controller: str = "watonobus"
    planner: PlannerName = PlannerName.OFFSET_PASS
    speed_planner: SpeedPlannerName | None = None
    speed_planning: SpeedPlanningConfig | None = None
    radar_mounts: dict[str, SE2] = field(default_factory=dict)
    serve_all_stops: bool = False
    decision: DecisionConfig = field(default_factory=DecisionConfig)
    path: LocalPathConfig = field(default_factory=LocalPathConfig)
    longitudinal: LongitudinalConfig = field(default_factory=LongitudinalConfig)
    lateral: LateralConfig = field(default_factory=LateralConfig)
    localization: LocalizationMode = LocalizationMode.EKF
    ekf: OdometryEkfConfig = field(default_factory=OdometryEkfConfig)
    inertial_ekf: PoseEkfConfig = field(default_factory=PoseEkfConfig)
    landmarks: LandmarkExtractionConfig = field(default_factory=LandmarkExtractionConfig)
    scan_matching: ScanMatchingSettings = field(default_factory=ScanMatchingSettings)
    amcl: AmclSettings = field(default_factory=AmclSettings)
    tracker: RadarTrackerConfig = field(default_factory=RadarTrackerConfig)
    reliability: ReliabilityConfig = field(default_factory=lambda: ReliabilityConfig(sensors=DEFAULT_SENSORS))
    v2i: AnticipationConfig = field(default_factory=AnticipationConfig)
    perception_mode: PerceptionMode = PerceptionMode.RADAR_TRACKING
    lidar_mounts: dict[str, np.ndarray] = field(default_factory=dict)
    cameras: tuple[PinholeCamera, ...] = ()
    raw_perception: RawPerceptionConfig = field(default_factory=RawPerceptionConfig)
    light_cameras: tuple[PinholeCamera, ...] = ()
    traffic_lights: TrafficLightTrackerConfig = field(default_factory=TrafficLightTrackerConfig)
    prediction: PredictionConfig = field(default_factory=lambda: PredictionConfig(horizon_s=6.0))
    occupancy_stop: OccupancyStopSettings | None = None
    nus_speed: NusSpeedSettings | None = None
    gem_sign_stop: GemSignStopSettings | None = None

    def __post_init__(self) -> None:
        # Decision reads the predicted paths this far ahead; shorter paths would silently shorten it.
        for name in ("crosswalk_lookahead_s", "vehicle_prediction_horizon_s"):
            need_s = getattr(self.decision, name)
            if self.prediction.horizon_s + 1e-9 < need_s:
                raise ConfigError(
                    f"StackConfig.prediction.horizon_s: expected at least the decision's {name} "
                    f"({need_s} s), got {self.prediction.horizon_s} s"
                )
        if not isinstance(self.perception_mode, PerceptionMode):
            raise ConfigError(
                f"StackConfig.perception_mode: expected one of {[m.value for m in PerceptionMode]}, "
                f"got {self.perception_mode!r}"
            )
        check_localization_inputs(self.localization, self.perception_mode, "StackConfig")
        if self.perception_mode.needs_raw_sensors and not self.lidar_mounts:
            raise ConfigError(
                f"StackConfig: perception_mode '{self.perception_mode}' expects lidar_mounts (the LiDAR "
                "calibration), got none"
            )


MODULE_PERIODS_US = {
    "localization": 10_000,
    "tracking": 100_000,
    "decision": 100_000,
    "planning": 100_000,
    "control": 20_000,
}
"""The stack's modules and how often each runs (and so pulses its heartbeat)."""


ModuleFaultHook = Callable[[str, int], str | None]
"""Fault-injection port for validation: (module, now_us) -> "hang", "raise" or None."""


def _injected_fault() -> None:
    raise RuntimeError("injected module fault")


_INERTIAL_MODES = (
    LocalizationMode.INERTIAL_EKF,
    LocalizationMode.LANDMARKS,
    LocalizationMode.SCAN_MATCHING,
    LocalizationMode.AMCL,
)
"""Localization modes that run the IMU-driven :class:`PoseEkf` (the others: the odometry EKF)."""

#: Lateral controllers that keep the legacy pull-over path (see :func:`_path_config`).
LEGACY_PATH_CONTROLLERS = (LateralControllerName.HEADING_PID, LateralControllerName.PURE_PURSUIT)


def _path_config(config: StackConfig) -> LocalPathConfig:
    """The planner's settings for the selected lateral controller.

    The laws measured at the front axle or the centre of gravity (Stanley, MPS, the MPC) and those
    aiming 2-3 m ahead (GEM, NUS) get the revised pull-over path (``LocalPathConfig``): route-anchored
    waypoints (the legacy grid swung S1's turn-in by up to 0.3 m between cycles), the body's clearance
    checked exactly (to first order, a body following the path exactly put its front corner over S1's
    taper) and the rear axle brought onto the spot's line (it ended 0.09 m short). The lookahead laws
    of 4 m and more (the default ``heading_pid``, ``pure_pursuit``) average the swing out and run
    outside the planned line: on the legacy path both met the service's outcomes (10 min, seed 0, clear),
    and on the revised one ``pure_pursuit`` left the road once in clear and once in snow (where: not
    investigated). They keep the legacy path, which also keeps the default's runs bit-identical to the
    previous release.
    """
    if config.lateral_controller in LEGACY_PATH_CONTROLLERS:
        return config.path
    return dataclasses.replace(
        config.path, route_anchored_waypoints=True, rear_axle_on_spot=True, exact_body_clearance=True
    )


class ShuttleStack:
    """Implements :class:`lastmile.core.vehicle.VehicleSoftware`."""

    def __init__(
        self,
        layers: SLayerDatabase,
        geometry: VehicleGeometry,
        config: StackConfig,
        fault_hook: ModuleFaultHook | None = None,
    ) -> None:
        self.layers = layers
        self.geometry = geometry
        self.config = config
        self.route: Polyline = layers.centerline
        # Beyond the curvature the route may ask of the front wheels alone (a mapped corner too tight
        # to round within the road), the rear wheels steer too, also at a kerb (road_edge.rear_steers).
        self._rear_steer_above_1pm = max_curvature_per_m(geometry) if geometry.all_wheel_steer else None
        self.profiler = ModuleProfiler(self._budgets_ms(config))
        # The EKF's zero-slip point is where the body has no sideways velocity: mid-wheelbase when the
        # rear wheels steer opposite to the front, the rear axle otherwise. A property of the vehicle.
        zero_slip_m = geometry.wheelbase_m / 2.0 if geometry.all_wheel_steer else 0.0
        inertial = config.localization in _INERTIAL_MODES
        self.ekf: OdometryEkf | PoseEkf = (
            PoseEkf(dataclasses.replace(config.inertial_ekf, zero_slip_offset_m=zero_slip_m))
            if inertial
            else OdometryEkf(dataclasses.replace(config.ekf, zero_slip_offset_m=zero_slip_m))
        )
        self.tracker = RadarObjectTracker(config.tracker)
        self.raw = (
            RawPerception(
                config.raw_perception, layers, config.lidar_mounts, config.cameras, config.radar_mounts
            )
            if config.perception_mode.needs_raw_sensors
            else None
        )
        # WATonoBus GNSS-denied mode: the raw chain's clusters correct the inertial EKF.
        self.landmarks = (
            LandmarkFusion(config.landmarks, layers)
            if config.localization is LocalizationMode.LANDMARKS and isinstance(self.ekf, PoseEkf)
            else None
        )
        # Snow Lion's scan-to-map mode: each rig frame registered to the point-cloud map.
        self.scan_matching = (
            ScanMatchFusion(config.scan_matching)
            if config.localization is LocalizationMode.SCAN_MATCHING and isinstance(self.ekf, PoseEkf)
            else None
        )
        # NUS's AMCL: a particle filter on the occupancy map, fed each rig frame's planar scan.
        self.amcl = (
            AmclFusion(config.amcl)
            if config.localization is LocalizationMode.AMCL and isinstance(self.ekf, PoseEkf)
            else None
        )
        # GEM's height-map obstacle stop (an option): a speed cap from each rig frame's grid.
        self.occupancy_stop = (
            OccupancyStop(config.occupancy_stop, geometry)
            if config.occupancy_stop is not None and config.perception_mode.needs_raw_sensors
            else None
        )
        # NUS's speed rule (an option): a cost map from each rig frame, a cap at every control step.
        self.nus_speed = (
            NusSpeedCap(config.nus_speed, geometry)
            if config.nus_speed is not None and config.perception_mode.needs_raw_sensors
            else None
        )
        # GEM's sign detector (an option): a stop sign seen ahead gives a full stop before it.
        self.sign_stop = (
            GemSignStop(
                config.gem_sign_stop, layers, geometry.front_from_rear_axle_m, config.decision.traffic_lights
            )
            if config.gem_sign_stop is not None and config.perception_mode.needs_raw_sensors
            else None
        )
        self.light_tracker = (
            TrafficLightTracker(layers.hdmap.traffic_lights, config.light_cameras, config.traffic_lights)
            if layers.hdmap.traffic_lights and config.light_cameras
            else None
        )
        self.predictor = MapAwarePredictor(layers.hdmap, config.prediction)
        self._predictions: PredictedPaths | None = None
        self.mission = MissionManager(
            stop_order=tuple(rs.stop.id for rs in layers.stops), serve_all=config.serve_all_stops
        )
        self.fsm = BehaviourStateMachine(
            layers=layers,
            geometry=geometry,
            mission=self.mission,
            config=config.decision,
            can_pass=config.planner in PASSING_PLANNERS,
        )
        self.planner = make_path_planner(
            config.planner,
            PlannerInputs(
                route=self.route,
                half_width_m=geometry.width_m / 2.0,
                curb_right_d_m=self._curb_right_d_m,
                body_behind_m=geometry.rear_overhang_m,
                body_ahead_m=geometry.length_m - geometry.rear_overhang_m,
                drivable=layers.hdmap.is_drivable,
                max_curvature_1pm=math.tan(geometry.max_steer_rad) / geometry.wheelbase_m,
                layers=layers,
                wheelbase_m=geometry.wheelbase_m,
                rear_steer_above_1pm=self._rear_steer_above_1pm,
            ),
            _path_config(config),
        )
        # Snow Lion's s-t + QP speed planner, when selected: the controller tracks its speed.
        self.speed = (
            StQpSpeedPlanning(
                self.route,
                geometry.width_m / 2.0,
                geometry.length_m,
                geometry.front_from_rear_axle_m,
                config.speed_planning,
            )
            if config.speed_planner is SpeedPlannerName.ST_QP
            else None
        )
        self.longitudinal = make_longitudinal_controller(config.longitudinal_controller, config.longitudinal)
        self.lateral = make_lateral_controller(config.lateral_controller, geometry, config.lateral)
        # GEM's twist controller drives a throttle/brake vehicle: every command then carries pedals.
        self._pedal_vehicle = isinstance(self.longitudinal, GemTwistLongitudinalController)
        self._tick = 0
        self._now = Stamp(0)
        self._speed_mps = 0.0
        self._wheel_angles_rad = (0.0, 0.0)  # front, rear: the last odometry frame's
        self._emergency_before = False  # decision's state at the last control step
        self._yaw_rate_radps = 0.0
        self._door_open = False
        self._person_in_doorway = False
        self._route_s: float | None = None
        self._route_d = 0.0
        self._decision: BehaviourDecision | None = None
        self._trajectory: Trajectory | None = None
        self._path: Polyline | None = None
        # The path fed to the lateral law when its own point is ahead of the planned one (per plan).
        self._lead_path: tuple[Polyline, float, Polyline] | None = None
        self._tracks: TrackedObjects = empty_tracks(Stamp(0))
        self._detections: list[DetectedObjects] = []
        self._command = ActuatorCommand(
            stamp=Stamp(0), accel_mps2=-1.0, steer_front_rad=0.0, steer_rear_rad=0.0
        )
        self.hmi = HmiComposer()
        self.turn_signals = TurnSignalRule(layers, geometry.length_m)
        self.v2i = CrossingAnticipation(layers.crosswalks, self.route.length_m, self.route.closed, config.v2i)
        # The vehicle's safety watches from outside: each module call is contained and pulses a
        # heartbeat; the directive it sends back is obeyed by decision and enforced by its own gate.
        self.guard = ModuleGuard()
        self._directive: SafetyDirective | None = None
        self._stop_reason = StopReason.NONE
        self.fault_hook = fault_hook
        self.rejected_frames = 0
        self._handlers = self._frame_handlers()

    @staticmethod
    def _budgets_ms(config: StackConfig) -> dict[str, float]:
        """Each profiled module's cycle budget: the period it runs at (the raw LiDAR chain at the
        LiDAR's 10 Hz). One module over it delays the next cycle."""
        tick_ms = config.tick_us / 1e3
        planning_ms = config.planning_period_ticks * tick_ms
        return {
            "estimation": tick_ms,
            "perception": 100.0,
            "landmarks": 100.0,
            "scan_matching": 100.0,
            "amcl": 100.0,
            **dict.fromkeys(
                ("tracking", "prediction", "decision", "planning", "planning_cycle"), planning_ms
            ),
            "control": config.control_period_ticks * tick_ms,
        }

    # ------------------------------------------------------------------------------------------------
    def tick(
        self, now: Stamp, frames: Sequence[SensorFrame], safety: SafetyDirective | None = None
    ) -> StackOutput:
        p = self.profiler
        hmi: list[HmiMessage] = []
        self._now = now
        if safety is not None:
            self._directive = safety
        with p.measure("estimation"):
            self._guarded("localization", now, self._ingest_all, frames)
        c = self.config
        status = None
        planning_cycle = self._tick % c.planning_period_ticks == 0
        raw = self.raw
        if raw is not None and raw.pending:
            with p.measure("perception"):
                # Perception and tracking are one module for the watchdog: the chain ends in tracks.
                done = self._guarded("tracking", now, raw.step, now, self.ekf.estimate, self._route_s)
            if done and self.landmarks is not None and raw.last_result is not None:
                with p.measure("landmarks"):
                    fuse = self.landmarks.fuse
                    self._guarded("localization", now, fuse, self.ekf, raw.last_result, self._route_s)
            if done and self.scan_matching is not None and raw.last_result is not None:
                with p.measure("scan_matching"):
                    match = self.scan_matching.fuse
                    self._guarded("localization", now, match, self.ekf, raw.last_result)
            if done and self.amcl is not None and raw.last_result is not None:
                with p.measure("amcl"):
                    self._guarded("localization", now, self.amcl.fuse, self.ekf, raw.last_result)
            if done and self.occupancy_stop is not None and raw.last_result is not None:
                with p.measure("perception"):
                    stop = self.occupancy_stop.update
                    self._guarded("tracking", now, stop, raw.last_result, *self._wheel_angles_rad)
            if done and self.nus_speed is not None and raw.last_result is not None:
                with p.measure("perception"):
                    self._guarded("tracking", now, self.nus_speed.update, raw.last_result, self.ekf.estimate)
            if done and self.sign_stop is not None and raw.last_result is not None:
                with p.measure("perception"):
                    result = raw.last_result
                    est = self.ekf.estimate(result.cloud.stamp)
                    self._guarded("tracking", now, self.sign_stop.update_from, result, est, self._route_s)
        if planning_cycle:
            with p.measure("tracking"):
                source = raw.tracks if raw is not None else self.tracker.tracks
                tracks = self._guarded("tracking", now, source, now)
                if isinstance(tracks, TrackedObjects):
                    self._tracks = tracks
            with p.measure("prediction"):
                paths = self._guarded("tracking", now, self.predictor.predict_objects, self._tracks)
                self._predictions = paths if isinstance(paths, PredictedPaths) else None
            # Behaviour, path and speed together: the planning cycle Snow Lion times (its 85.1 ms p95).
            with p.measure("planning_cycle"):
                with p.measure("decision"):
                    self._guarded("decision", now, self._decide, now)
                with p.measure("planning"):
                    self._guarded("planning", now, self._plan, now)
        if self._tick % c.control_period_ticks == 0:
            with p.measure("control"):
                self._guarded("control", now, self._control, now)
        if planning_cycle:
            status = self._status(now)
            takeover = self._directive.takeover_request if self._directive is not None else False
            hmi.extend(self.hmi.step(now, self._decision, takeover))
        self._tick += 1
        return StackOutput(
            command=self._command,
            status=status,
            decision=self._decision,
            hmi=tuple(hmi),
            heartbeats=self.guard.drain(),
            diagnostics=self._diagnostics(now, planning_cycle),
            stop_reason=self._stop_reason,
            tracks=self._tracks if planning_cycle else None,
            trajectory=self._trajectory if planning_cycle else None,
            detections=self._drain_detections() if planning_cycle else None,
        )

    def _drain_detections(self) -> tuple[DetectedObjects, ...]:
        """What the tracker consumed since the last planning cycle (radar lists or fused objects)."""
        if self.raw is not None:
            return self.raw.drain_detections()
        out, self._detections = tuple(self._detections), []
        return out

    def report(self) -> VehicleReport:
        """Compute time per module, the stack's counters and the raw perception's summary."""
        counters = {"rejected_frames": self.rejected_frames, "v2i_reports_received": self.v2i.received}
        counters.update(self.turn_signals.counters())
        perception: dict[str, float | int | None] = {}
        if self.raw is not None:
            st = self.raw.stats
            offsets = st.curb_offsets_m
            perception = {
                "rig_frames": st.rig_frames,
                "incomplete_frames": st.incomplete_frames,
                "skipped_no_pose": st.skipped_no_pose,
                "clusters_per_frame": st.clusters / max(st.rig_frames, 1),
                "curb_valid_frames": st.curb_valid,
                "curb_offset_median_m": float(np.median(offsets)) if offsets else None,
            }
            if self.raw.detector is not None:
                perception["detections_per_frame"] = st.detections / max(st.rig_frames, 1)
                perception["clusters_replaced_per_frame"] = st.clusters_replaced / max(st.rig_frames, 1)
        if self.landmarks is not None:
            counters.update(self.landmarks.counters())
            perception["landmark_update_cpu_p50_ms"] = self.landmarks.cpu_p50_ms()
        if self.scan_matching is not None:
            counters.update(self.scan_matching.counters())
            perception["scan_match_update_cpu_p50_ms"] = self.scan_matching.cpu_p50_ms()
        if self.speed is not None:
            counters.update(
                speed_plans=self.speed.replans,
                speed_cycles=self.speed.cycles,
                speed_unsolved=self.speed.unsolved,
            )
        if self.amcl is not None:
            counters.update(self.amcl.counters())
            perception["amcl_update_cpu_p50_ms"] = self.amcl.cpu_p50_ms()
        if self.occupancy_stop is not None:
            counters.update(self.occupancy_stop.counters())
        if self.nus_speed is not None:
            counters.update(self.nus_speed.counters())
        if self.sign_stop is not None:
            counters.update(self.sign_stop.counters())
            perception.update(self.sign_stop.summary())
        return VehicleReport(modules=self.profiler.summary(), counters=counters, perception=perception)

    def _guarded(self, module: str, now: Stamp, fn: Callable[..., object], *args: object) -> object:
        fault = self.fault_hook(module, int(now)) if self.fault_hook is not None else None
        if fault == "hang":
            return None  # a hung module neither runs nor pulses: its watchdog must notice
        if fault == "raise":
            fn, args = _injected_fault, ()
        return self.guard.call(module, now, fn, *args)

    def _diagnostics(self, now: Stamp, planning_cycle: bool) -> StackDiagnostics:
        """What the vehicle's safety checks each tick (the pose's integrity on planning cycles)."""
        est = self.ekf.estimate(now)
        front_s = self._route_s + self.geometry.front_from_rear_axle_m if self._route_s is not None else None
        return StackDiagnostics(
            stamp=now,
            estimate=est if planning_cycle else None,
            gate_rejections_total=self.ekf.rejected_fixes,
            gross_rejections_total=self.ekf.gross_rejections,
            speed_mps=est.speed_mps if est.valid else self._speed_mps,
            front_route_s_m=front_s,
        )

    def _ingest_all(self, frames: Sequence[SensorFrame]) -> None:
        for frame in frames:
            try:
                frame.validate()
            except MessageError:
                # A corrupt frame is dropped, never fed to a filter; the reliability monitor has
                # already flagged its stream as garbage.
                self.rejected_frames += 1
                continue
            self._ingest(frame)

    def _curb_right_d_m(self, s_m: FloatArray) -> FloatArray:
        return self.layers.curb_right_d_m[self.layers.record_indices(s_m)]

    def _ingest(self, frame: SensorFrame) -> None:
        handler = self._handlers.get(type(frame))
        if handler is not None:  # frames for others (operator inputs: the vehicle safety's) are skipped
            handler(frame)

    def _frame_handlers(self) -> dict[type, Callable[[Any], object]]:
        """Which module each frame type feeds: one table, so a new frame type is one entry."""
        handlers: dict[type, Callable[[Any], object]] = {
            GnssInsFrame: self.ekf.update_gnss,
            RadarFrame: self._on_radar,
            DoorSensorFrame: self._on_door,
            StopCallFrame: self.mission.on_call,
            DropOffRequestFrame: self.mission.on_drop_off,
            CrossingPresenceFrame: self.v2i.on_frame,
        }
        handlers.update(self._localization_handlers())
        if self.raw is not None:
            # Raw perception fuses the radar objects with the LiDAR clusters (no separate radar tracker).
            for kind in (LidarSweep, CameraDetections, RadarFrame):
                handlers[kind] = self._on_raw
        if self.light_tracker is not None:
            handlers[TrafficLightDetections] = self._on_lights
        return handlers

    def _localization_handlers(self) -> dict[type, Callable[[Any], object]]:
        """The motion inputs of the localization mode, bound once: the inertial EKF predicts from the
        IMU and takes wheel speed as a measurement; the odometry EKF predicts from wheel speed and the
        latest yaw rate."""
        ekf = self.ekf

        def odometry(frame: WheelOdometryFrame) -> None:
            self._speed_mps = frame.speed_mps
            self._wheel_angles_rad = (frame.steer_front_rad, frame.steer_rear_rad)

        pedal_law = (
            self.longitudinal if isinstance(self.longitudinal, GemTwistLongitudinalController) else None
        )

        def imu(frame: ImuFrame) -> None:
            self._yaw_rate_radps = frame.yaw_rate_radps
            if pedal_law is not None:  # GEM's throttle loop closes on the IMU's acceleration
                pedal_law.observe_imu(frame.accel_x_mps2)

        if isinstance(ekf, PoseEkf):

            def inertial_odometry(frame: WheelOdometryFrame) -> None:
                odometry(frame)
                ekf.wheel_speed(frame.stamp, frame.speed_mps)

            def inertial_imu(frame: ImuFrame) -> None:
                imu(frame)
                ekf.imu(frame.stamp, frame.yaw_rate_radps, frame.accel_x_mps2)

            return {WheelOdometryFrame: inertial_odometry, ImuFrame: inertial_imu}

        wheelbase_m = self.geometry.wheelbase_m

        def odometry_predicts(frame: WheelOdometryFrame) -> None:
            odometry(frame)
            # The zero-slip point follows the measured wheel angles: the rear wheels are kept
            # straight at a curb, and the rear axle then no longer slides outwards.
            lever_m = zero_slip_offset_m(wheelbase_m, frame.steer_front_rad, frame.steer_rear_rad)
            ekf.predict(frame.stamp, frame.speed_mps, self._yaw_rate_radps, lever_m)

        return {WheelOdometryFrame: odometry_predicts, ImuFrame: imu}

    def _on_raw(self, frame: LidarSweep | CameraDetections | RadarFrame) -> None:
        assert self.raw is not None
        self.raw.on_frame(frame, self._now)

    def _on_radar(self, frame: RadarFrame) -> None:
        est = self.ekf.estimate(frame.stamp)
        mount = self.config.radar_mounts.get(frame.sensor_id)
        if est.valid and mount is not None:
            self.tracker.update(frame, est.map_from_base, mount)
            size_m = self.config.raw_perception.fusion.radar_only_size_m
            self._detections.append(radar_detections(frame, est.map_from_base.compose(mount), size_m))

    def _on_door(self, frame: DoorSensorFrame) -> None:
        self._door_open = frame.door_open
        self._person_in_doorway = frame.person_in_doorway

    def _on_lights(self, frame: TrafficLightDetections) -> None:
        assert self.light_tracker is not None
        est = self.ekf.estimate(frame.stamp)
        if est.valid:
            self.light_tracker.update(frame, est.map_from_base)

    def _decide(self, now: Stamp) -> None:
        est = self.ekf.estimate(now)
        if not est.valid:
            self._decision = None
            self._stop_reason = StopReason.NONE
            return
        pose = est.map_from_base
        f = self.route.project(pose.x_m, pose.y_m, hint_s_m=self._route_s, window_m=20.0)
        self._route_s, self._route_d = f.s_m, f.d_m
        self._decision = self.fsm.step(
            DecisionInput(
                stamp=now,
                map_from_base=pose,
                speed_mps=est.speed_mps,
                route_s_m=f.s_m,
                route_d_m=f.d_m,
                tracks=self._tracks,
                door_open=self._door_open,
                person_in_doorway=self._person_in_doorway,
                trajectory=self._trajectory,
                safety=self._directive,
                traffic_lights=self.light_tracker.states() if self.light_tracker is not None else None,
                predictions=self._predictions,
                accel_mps2=self._command.accel_mps2,
            )
        )
        self._stop_for_signs(now, f.s_m, est.speed_mps)
        self._anticipate(now, f.s_m, est.speed_mps)

    def _stop_for_signs(self, now: Stamp, route_s_m: float, speed_mps: float) -> None:
        """GEM's detected stop sign ahead: its stop point, unless decision's own is nearer."""
        d = self._decision
        if self.sign_stop is None or d is None:
            return
        front_s = route_s_m + self.geometry.front_from_rear_axle_m
        stop, why = self.sign_stop.step(int(now) / 1e6, front_s, speed_mps)
        # Only while driving on: a pull-over, boarding, merge or emergency stop keeps its own point.
        if d.state not in (BehaviourState.NORMAL_DRIVING, BehaviourState.INTERSECTION) or not why:
            return
        ds = self.route.ds_m
        if stop is not None and (d.stop_at_s_m is None or ds(front_s, stop) < ds(front_s, d.stop_at_s_m)):
            self._decision = dataclasses.replace(
                d, stop_at_s_m=stop, reason=f"{d.reason}; {why}", stop_reason=StopReason.DETECTED_SIGN
            )
        else:
            self._decision = dataclasses.replace(d, reason=f"{d.reason}; {why}")

    def _anticipate(self, now: Stamp, route_s_m: float, speed_mps: float) -> None:
        """A crossing the infrastructure reports occupied: stop before it, unless a nearer stop binds."""
        d = self._decision
        self._stop_reason = d.stop_reason if d is not None else StopReason.NONE
        if d is None or d.state != BehaviourState.NORMAL_DRIVING or not self.v2i.reports:
            return
        front_s = route_s_m + self.geometry.front_from_rear_axle_m
        stop = self.v2i.stop_point(now, front_s, speed_mps)
        if stop is not None and self.v2i.nearer(stop, d.stop_at_s_m, front_s):
            self._decision = dataclasses.replace(
                d,
                stop_at_s_m=stop,
                reason=f"{d.reason}; stop for crosswalk (infrastructure reports pedestrians)",
                stop_reason=StopReason.INFRASTRUCTURE_CROSSING,
            )
            self._stop_reason = StopReason.INFRASTRUCTURE_CROSSING

    def _plan(self, now: Stamp) -> None:
        if self._decision is None or self._route_s is None:
            return
        obstacles = route_obstacles(
            self._tracks, self.route, self._route_s, self.geometry.front_from_rear_axle_m
        )
        self._trajectory = self.planner.plan(now, self._route_s, self._route_d, self._decision, obstacles)
        self._path = Polyline(self._trajectory.points[:, :2])
        if self.speed is not None:
            self._plan_speed(now, obstacles)

    def _plan_speed(self, now: Stamp, obstacles: list[RouteObstacle]) -> None:
        """The s-t + QP speed planner's cycle (it replans only on events)."""
        d, path, est = self._decision, self._path, self.ekf.estimate(now)
        assert self.speed is not None and d is not None and path is not None and self._trajectory is not None
        if not est.valid or self._route_s is None:
            return
        front_s = self._route_s + self.geometry.front_from_rear_axle_m
        gap = terminal_gap_m(d, obstacles, self.route, front_s)
        following = d.stop_at_s_m is not None and gap is None
        self.speed.update(
            SpeedInput(
                now_s=int(now) / 1e6,
                trajectory=self._trajectory,
                front_s_m=front_s,
                path_s_m=path.project(est.map_from_base.x_m, est.map_from_base.y_m).s_m,
                speed_mps=est.speed_mps,
                accel_mps2=self._command.accel_mps2,
                cap_mps=min(d.speed_limit_mps, self._trajectory.speed_limit_mps),
                stop_gap_m=self._planner_stop_gap_m(gap, front_s),
                obstacles=obstacles,
                following=following,
            )
        )

    def _control(self, now: Stamp) -> None:
        d, path, est = self._decision, self._path, self.ekf.estimate(now)
        dt = self.config.control_period_ticks * self.config.tick_us / 1e6
        if d is None or path is None or not est.valid or self._route_s is None:
            # No pose or plan yet: hold the brakes.
            pedal = self._pedal_vehicle
            self._command = ActuatorCommand(
                stamp=now,
                accel_mps2=-1.5,
                steer_front_rad=0.0,
                steer_rear_rad=0.0,
                throttle=0.0 if pedal else None,
                brake=gem_brake_pedal(1.5) if pedal else None,
            )
            self.longitudinal.reset(est.speed_mps if est.valid else 0.0)
            return
        pose = est.map_from_base
        front_s = self._route_s + self.geometry.front_from_rear_axle_m
        # Route s advances between planning cycles; extrapolate it so the stop point stays sharp at 50 Hz.
        fp = self.route.project(pose.x_m, pose.y_m, hint_s_m=self._route_s, window_m=5.0)
        front_s = fp.s_m + self.geometry.front_from_rear_axle_m
        gap = stopping_gap_m(d.stop_at_s_m, front_s)
        if gap is not None and d.stop_at_s_m is not None:
            gap = self.route.ds_m(front_s, d.stop_at_s_m)  # the shorter way round on the loop
        assert self._trajectory is not None
        gap = self._planner_stop_gap_m(gap, front_s)
        path_s = path.project(pose.x_m, pose.y_m).s_m
        # A lateral controller with a speed law of its own (GEM's v_max = sqrt(0.5 r)) lowers the cap.
        cap = self.lateral.speed_cap_mps(
            path,
            path_s,
            min(d.speed_limit_mps, self._trajectory.speed_limit_mps),
            self.config.longitudinal.nominal_accel_mps2,
        )
        if self.occupancy_stop is not None:  # GEM's obstacle stop lowers it further
            cap = self.occupancy_stop.cap_mps(cap)
        if self.nus_speed is not None:  # and NUS's rule: steering angle and cost map
            cap = self.nus_speed.cap_mps(cap, *self._wheel_angles_rad)
        if self.sign_stop is not None:  # and GEM's constant deceleration to a detected stop sign
            cap = self.sign_stop.cap_mps(cap, front_s)
        emergency_now = d.state == BehaviourState.EMERGENCY_STOP
        if self._emergency_before and not emergency_now:
            # Released from an emergency stop, the shuttle stands wherever it stopped: the target ahead
            # is a new stop, not one it came to rest short of (whose restart the law holds back within
            # restart_gap_m). Without this a pull-over interrupted 1 m short of its spot stood for ever.
            self.longitudinal.reset(est.speed_mps)
        self._emergency_before = emergency_now
        v_ref = self.longitudinal.reference_speed_mps(self._trajectory, path_s, cap)
        if self.speed is not None:
            v_plan, gap = self.speed.reference(int(now) / 1e6, front_s, gap, est.speed_mps)
            v_ref = min(v_ref, v_plan)
        accel = self.longitudinal.step(dt, est.speed_mps, v_ref, gap)
        self.lateral.set_speed_reference(v_ref)  # a coupled lateral model predicts with it
        emergency = d.state == BehaviourState.EMERGENCY_STOP and est.speed_mps > 0.05
        # In a bay the rear wheels stay straight: counter-steering them would swing the tail into the
        # curb as the shuttle turns out of (or straightens into) the bay.
        at_curb = (
            d.state in (BehaviourState.PULLOVER, BehaviourState.ONBOARDING, BehaviourState.MERGING)
            or (d.stop_reason == StopReason.MINIMAL_RISK_MANOEUVRE and d.pullover_spot is not None)
        ) and not self._bend_needs_rear_steer(fp.s_m)
        steer_f, steer_r = self.lateral.step(
            dt, pose, est.speed_mps, self._path_for_law(path, not at_curb), rear_steer=not at_curb
        )
        # A throttle/brake vehicle's command carries the twist controller's pedals.
        law = self.longitudinal
        pedals = law.pedals if isinstance(law, GemTwistLongitudinalController) else None
        self._command = ActuatorCommand(
            stamp=now,
            accel_mps2=accel,
            steer_front_rad=steer_f,
            steer_rear_rad=steer_r,
            door_open=d.door_open,
            emergency_brake=emergency,
            turn_signal=self.turn_signals.signal(d, front_s, emergency),
            throttle=pedals.throttle if pedals is not None else None,
            brake=pedals.brake if pedals is not None else None,
        )

    def _planner_stop_gap_m(self, gap_m: float | None, front_s_m: float) -> float | None:
        """The nearer of decision's stop gap and the planner's (a truncated route, a lane stop)."""
        assert self._trajectory is not None
        stop = self._trajectory.stop_at_route_s_m
        if stop is None:
            return gap_m
        planned = self.route.ds_m(front_s_m, stop)
        return planned if gap_m is None else min(gap_m, planned)

    def _bend_needs_rear_steer(self, rear_s_m: float) -> bool:
        """A bend under or just ahead of the body that the front wheels alone cannot follow (the
        planner places the body for the same answer)."""
        if self._rear_steer_above_1pm is None:
            return False
        g = self.geometry
        steers = rear_steers(
            self.route,
            np.array([rear_s_m]),
            g.wheelbase_m,
            g.length_m - g.rear_overhang_m,
            self._rear_steer_above_1pm,
        )
        return bool(steers[0])

    def _path_for_law(self, path: Polyline, rear_steer: bool) -> Polyline:
        """The path of the lateral law's own point: the planned one (laid for the rear axle, or the centre
        of the wheelbase with all-wheel steer) carried forward to the front axle (Stanley) or the centre
        of gravity (MPC). Fed the rear axle's path, Stanley puts the front axle on it and stops in a bay
        with the body angled, its tail off the curb."""
        lead = self.lateral.path_lead_m(rear_steer)
        if lead == 0.0:
            return path
        cached = self._lead_path
        if cached is None or cached[0] is not path or cached[1] != lead:
            cached = self._lead_path = (path, lead, path_ahead_of(path, lead))
        return cached[2]

    def _status(self, now: Stamp) -> VehicleStatus:
        est = self.ekf.estimate(now)
        d = self._decision
        return VehicleStatus(
            stamp=now,
            map_from_base=est.map_from_base if est.valid else None,
            speed_mps=est.speed_mps,
            state=d.state if d is not None else BehaviourState.NORMAL_DRIVING,
            route_s_m=self._route_s if self._route_s is not None else math.nan,
            door_open=self._door_open,
            healthy=est.valid,
        )
