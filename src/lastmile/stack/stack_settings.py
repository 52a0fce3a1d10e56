"""The vehicle software's part of a run configuration: which modules run, and their parameters.

Loaded from the ``[stack]`` table of a run configuration TOML (``lastmile run --config FILE``); unknown
keys and names are rejected with one line. Implementations are chosen by name from explicit registries.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np

from lastmile.control.lateral import LateralConfig, LateralControllerName
from lastmile.control.longitudinal import LongitudinalConfig, LongitudinalControllerName
from lastmile.core.config import check_range
from lastmile.core.errors import ConfigError
from lastmile.core.perception_mode import PerceptionMode
from lastmile.decision.decision_config import DecisionConfig
from lastmile.localization import camera_mount_file
from lastmile.localization.amcl_localization import AmclSettings
from lastmile.localization.ekf_config import PoseEkfConfig
from lastmile.localization.landmark_extraction import LandmarkExtractionConfig
from lastmile.localization.lidar_mount_file import check_covers, read_lidar_mounts
from lastmile.localization.odometry_ekf import OdometryEkfConfig
from lastmile.localization.scan_match_localization import ScanMatchingSettings
from lastmile.perception.lidar_detector import LidarDetectorConfig
from lastmile.perception.pedestrian_verification import PedestrianVerificationConfig
from lastmile.planning.local_path import LocalPathConfig
from lastmile.planning.planners import PlannerName
from lastmile.planning.speed_planning import SpeedPlannerName, SpeedPlanningConfig
from lastmile.safety.failsafe import FailSafeConfig
from lastmile.safety.hardware_watchdog import HardwareWatchdogConfig
from lastmile.stack.gem_sign_stop import GemSignStopSettings
from lastmile.stack.nus_speed_cap import NusSpeedSettings
from lastmile.stack.occupancy_stop import OccupancyStopSettings


class LocalizationMode(StrEnum):
    """Localization modes by name."""

    EKF = "ekf"
    """Pose EKF driven by wheel odometry and IMU yaw rate, corrected by gated RTK GNSS/INS fixes, with
    late-fix replay (:mod:`lastmile.localization.odometry_ekf`)."""
    INERTIAL_EKF = "inertial_ekf"
    """The IMU-driven EKF of :mod:`lastmile.localization.ekf`: accelerometer and gyro prediction with
    bias and scale states, wheel speed as a measurement, antenna lever arm, correlated GNSS error and
    consistency-based re-acquisition after outages (built for real drives; see its README)."""
    LANDMARKS = "landmarks"
    """WATonoBus GNSS-denied localization: the ``inertial_ekf`` filter, also corrected by the light
    poles and building facades the raw LiDAR chain sees, associated with the map's landmark records
    (:mod:`lastmile.localization.landmark_extraction`, :mod:`lastmile.localization.landmark_localization`).
    Needs raw perception (radars give object lists only)."""
    SCAN_MATCHING = "scan_matching"
    """Snow Lion's scan-to-map localization: the ``inertial_ekf`` filter, also corrected by each LiDAR
    rig frame registered to a point-cloud map (``[stack.scan_matching] map``, from ``lastmile map
    build``; :mod:`lastmile.localization.scan_match_localization`). Needs raw perception."""
    AMCL = "amcl"
    """NUS's AMCL: the ``inertial_ekf`` filter, also corrected by a particle filter on the 2-D occupancy
    map (``[stack.amcl] map``, the YAML ``lastmile map build`` writes beside the PCD) fed each LiDAR rig
    frame's planar scan (:mod:`lastmile.localization.amcl_localization`). Needs raw perception."""


_FAILSAFE = FailSafeConfig()
_WATCHDOG = HardwareWatchdogConfig()


@dataclass(frozen=True, slots=True, kw_only=True)
class SafetySettings:
    """The vehicle safety's parameters that a run configuration may set (the rest are the defaults of
    :class:`~lastmile.safety.failsafe.FailSafeConfig`).

    Attributes:
        max_decel_mps2: emergency-stop deceleration (the vehicle's maximum).
        mrm_decel_mps2: the minimal risk manoeuvre's comfortable deceleration.
        default_speed_cap_mps: speed cap of SPEED_LIMIT signals that carry none (Snow Lion: 0.5 m/s).
        watchdog_timeout_us: the hardware watchdog trips when the command stream is silent this long.
    """

    max_decel_mps2: float = _FAILSAFE.max_decel_mps2
    mrm_decel_mps2: float = _FAILSAFE.mrm_decel_mps2
    default_speed_cap_mps: float = _FAILSAFE.default_speed_cap_mps
    watchdog_timeout_us: int = _WATCHDOG.timeout_us

    def __post_init__(self) -> None:
        check_range("stack.safety.max_decel_mps2", self.max_decel_mps2, 1.0, 10.0)
        check_range("stack.safety.mrm_decel_mps2", self.mrm_decel_mps2, 0.1, self.max_decel_mps2)
        check_range("stack.safety.default_speed_cap_mps", self.default_speed_cap_mps, 0.0, 20.0 / 3.6)
        check_range("stack.safety.watchdog_timeout_us", self.watchdog_timeout_us, 10_000, 1_000_000)

    def failsafe(self) -> FailSafeConfig:
        return FailSafeConfig(
            max_decel_mps2=self.max_decel_mps2,
            mrm_decel_mps2=self.mrm_decel_mps2,
            default_speed_cap_mps=self.default_speed_cap_mps,
        )

    def watchdog(self) -> HardwareWatchdogConfig:
        return HardwareWatchdogConfig(
            timeout_us=self.watchdog_timeout_us, brake_decel_mps2=self.max_decel_mps2
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class StackSettings:
    """Which modules the vehicle software runs, and their parameters.

    Attributes:
        perception: what the stack perceives through (default: the raw sensors).
        lateral_controller: heading_pid (WATonoBus, default), pure_pursuit, nus_pure_pursuit, stanley,
            model_predictive_stanley, snow_lion_mpc (its speed reference is the longitudinal one),
            gem_waypoint (:class:`lastmile.control.lateral.LateralControllerName`).
        longitudinal_controller: watonobus (default) or cascaded_pi (aUToronto's trapezoidal profile
            and cascaded PI) or gem_twist (GEM's twist controller: the command carries throttle and
            brake pedals, and the simulator moves the shuttle with its pedal plant).
        planner: offset_pass (default: WATonoBus's potential field and Bezier curves, and passes of
            a stationary obstacle blocking the lane by the adjacent lane; ``decision.pass_rule``) or
            potential_field_bezier (the same without passing: the shuttle waits behind it) or
            snow_lion_behaviour (Snow Lion's behaviour planner; passes as offset_pass does) or
            lattice (aUToronto's A* over a lattice of the route lane and its sibling lanelets).
        speed_planner: None or controller (the default: the longitudinal law alone) or st_qp (Snow
            Lion's s-t search + OSQP QP over predicted road users, eqs. 1-2 and the terminal stop,
            replanned on events; :mod:`lastmile.planning.speed_planning`).
        speed_planning: its parameters (None: the defaults).
        localization: the name of the registered implementation.
        cruise_speed_mps: the shuttle's cruise speed (None: decision's default, 20 km/h).
        serve_all_stops: timetable mode (every stop) instead of on request.
        decision, path, longitudinal, lateral: the modules' parameters (their defaults).
        ekf, inertial_ekf: the parameters of the ``ekf`` and ``inertial_ekf`` localization modes
            (``landmarks`` runs the ``inertial_ekf`` filter).
        landmarks: the ``landmarks`` mode's pole and facade extraction.
        scan_matching: the ``scan_matching`` mode's map and matcher (the map is read and checked when
            that mode is selected).
        amcl: the ``amcl`` mode's occupancy map and particle filter (the map likewise).
        safety: the vehicle safety's parameters.
        lidar_detector: a learned LiDAR detector (``[stack.lidar_detector]``, an ONNX model file and
            its BEV grid; :mod:`lastmile.perception.lidar_detector`) run on every rig frame beside
            the clustering, its boxes going through late fusion to the tracker (raw perception only).
        lidar_mounts: a LiDAR mounts file (``[[lidar_mount]]`` tables, as ``lastmile calibrate lidar
            --out`` writes them; :mod:`lastmile.localization.lidar_mount_file`) the stack runs on instead
            of the vehicle's nominal mounts (in simulation, the simulator's true ones). Empty: the
            nominal mounts. Raw perception only; it must name every LiDAR of the vehicle.
        occupancy_stop: GEM's height-map obstacle stop (``[stack.occupancy_stop]``,
            :mod:`lastmile.stack.occupancy_stop`): the speed capped at v = d / 5 - 1 for the nearest
            occupied cell on the arc of the wheel angles (raw perception only; off by default).
        nus_speed: NUS's speed rule (``[stack.nus_speed]``, :mod:`lastmile.stack.nus_speed_cap`): the
            speed capped at the lower of a steering-angle safe speed and a safe speed from the mean
            cost ahead in NUS's cost map of each rig frame (raw perception only; off by default).
        gem_sign_stop: GEM's LiDAR sign detector as a stop (``[stack.gem_sign_stop]``,
            :mod:`lastmile.stack.gem_sign_stop`): a stop sign detected ahead in the route's corridor
            (by default only where the map has one) gives a full stop before it, approached at GEM's
            a = -v^2 / (2 d) (raw perception only; off by default).
        pedestrian_verification: NUS's pedestrian verification in the late fusion
            (``[stack.pedestrian_verification]``, :mod:`lastmile.perception.pedestrian_verification`):
            a cluster is a pedestrian only when person-shaped and confirmed by a camera pedestrian
            box (raw perception only; off by default: WATonoBus's camera boxes name the class).
        camera_mounts: a camera mounts file (``[[camera_mount]]`` tables, as ``lastmile calibrate camera
            --out`` writes them; :mod:`lastmile.localization.camera_mount_file`) whose mounts the stack
            uses instead of the vehicle's nominal ones (in simulation, the simulator's true ones), for
            raw perception's cameras and the traffic-light cameras alike. Empty: the nominal mounts. It
            must name every camera of the vehicle.
    """

    perception: PerceptionMode = PerceptionMode.LIDAR_CAMERA_RADAR
    lateral_controller: LateralControllerName = LateralControllerName.HEADING_PID
    longitudinal_controller: LongitudinalControllerName = LongitudinalControllerName.WATONOBUS
    planner: PlannerName = PlannerName.OFFSET_PASS
    speed_planner: SpeedPlannerName | None = None
    speed_planning: SpeedPlanningConfig | None = None
    localization: LocalizationMode = LocalizationMode.EKF
    cruise_speed_mps: float | None = None
    serve_all_stops: bool = False
    decision: DecisionConfig = field(default_factory=DecisionConfig)
    path: LocalPathConfig = field(default_factory=LocalPathConfig)
    longitudinal: LongitudinalConfig = field(default_factory=LongitudinalConfig)
    lateral: LateralConfig = field(default_factory=LateralConfig)
    ekf: OdometryEkfConfig = field(default_factory=OdometryEkfConfig)
    inertial_ekf: PoseEkfConfig = field(default_factory=PoseEkfConfig)
    landmarks: LandmarkExtractionConfig = field(default_factory=LandmarkExtractionConfig)
    scan_matching: ScanMatchingSettings = field(default_factory=ScanMatchingSettings)
    amcl: AmclSettings = field(default_factory=AmclSettings)
    safety: SafetySettings = field(default_factory=SafetySettings)
    lidar_detector: LidarDetectorConfig | None = None
    lidar_mounts: str = ""
    occupancy_stop: OccupancyStopSettings | None = None
    nus_speed: NusSpeedSettings | None = None
    gem_sign_stop: GemSignStopSettings | None = None
    pedestrian_verification: PedestrianVerificationConfig | None = None
    camera_mounts: str = ""

    def __post_init__(self) -> None:
        if self.lidar_detector is not None and not self.perception.needs_raw_sensors:
            raise ConfigError(
                f"stack.lidar_detector: expected perception = '{PerceptionMode.LIDAR_CAMERA_RADAR}' (the "
                f"detector reads the LiDAR sweeps), got perception = '{self.perception}'"
            )
        check_localization_inputs(self.localization, self.perception, "stack")
        if self.camera_mounts:
            self.calibrated_camera_mounts()  # a missing or bad file is one line now, not at the build
        if self.lidar_mounts:
            self.calibrated_lidar_mounts()  # a missing or bad file is one line now, not at the build
        for key, why in (
            ("occupancy_stop", "the grid is built from the LiDAR sweeps"),
            ("nus_speed", "its cost map is built from the LiDAR sweeps"),
            ("gem_sign_stop", "the detector reads the LiDAR sweeps' intensities"),
            ("pedestrian_verification", "it verifies LiDAR clusters"),
        ):
            if getattr(self, key) is not None and not self.perception.needs_raw_sensors:
                raise ConfigError(
                    f"stack.{key}: expected perception = '{PerceptionMode.LIDAR_CAMERA_RADAR}' ({why}), "
                    f"got perception = '{self.perception}'"
                )
        if self.localization is LocalizationMode.SCAN_MATCHING:
            self.scan_matching.load_map()  # a missing or bad map is one line now, not at the first scan
        if self.localization is LocalizationMode.AMCL:
            self.amcl.load_map()
        # Decision checks the pass's room and sight with the clearance the planner keeps: one value.
        planned, decided = self.path.passing.clearance_m, self.decision.passing.clearance_m
        if planned != decided:
            raise ConfigError(
                f"stack.path.passing.clearance_m: expected the same as stack.decision.passing.clearance_m "
                f"({decided} m), got {planned} m"
            )
        if self.cruise_speed_mps is not None:
            # The shuttle's operating speeds: up to its 20 km/h top speed.
            check_range("stack.cruise_speed_mps", self.cruise_speed_mps, 0.5, 20.0 / 3.6 + 1e-9)

    def calibrated_lidar_mounts(
        self, lidar_ids: tuple[str, ...] | None = None
    ) -> dict[str, np.ndarray] | None:
        """The mounts of ``lidar_mounts`` by LiDAR id, or None when the nominal ones are used.

        Args:
            lidar_ids: the vehicle's LiDARs, which the file must name exactly (None: not checked).
        """
        if not self.lidar_mounts:
            return None
        if not self.perception.needs_raw_sensors:
            raise ConfigError(
                f"stack.lidar_mounts: expected perception = '{PerceptionMode.LIDAR_CAMERA_RADAR}' (the "
                f"mounts place the LiDAR sweeps), got perception = '{self.perception}'"
            )
        try:
            mounts = read_lidar_mounts(Path(self.lidar_mounts))
            if lidar_ids is not None:
                check_covers(mounts, lidar_ids, str(self.lidar_mounts))
        except ConfigError as exc:
            raise ConfigError(f"stack.lidar_mounts: {exc}") from None
        return mounts

    def calibrated_camera_mounts(
        self, camera_ids: tuple[str, ...] | None = None
    ) -> dict[str, np.ndarray] | None:
        """``camera_from_base`` of ``camera_mounts`` by camera id, or None when the nominal ones are used.

        Args:
            camera_ids: the vehicle's cameras, which the file must name exactly (None: not checked).
        """
        if not self.camera_mounts:
            return None
        try:
            mounts = camera_mount_file.read_camera_mounts(Path(self.camera_mounts))
            if camera_ids is not None:
                camera_mount_file.check_covers(mounts, camera_ids, str(self.camera_mounts))
        except ConfigError as exc:
            raise ConfigError(f"stack.camera_mounts: {exc}") from None
        return mounts


_LIDAR_MODES = (LocalizationMode.LANDMARKS, LocalizationMode.SCAN_MATCHING, LocalizationMode.AMCL)
"""Localization modes corrected by the raw LiDAR's clouds."""


def check_localization_inputs(mode: LocalizationMode, perception: PerceptionMode, where: str) -> None:
    """Raise a :class:`ConfigError` if ``mode`` needs sensor data that ``perception`` does not give."""
    if mode in _LIDAR_MODES and not perception.needs_raw_sensors:
        raise ConfigError(
            f"{where}.localization '{mode}': expected raw LiDAR perception "
            f"'{PerceptionMode.LIDAR_CAMERA_RADAR}', got perception '{perception}' "
            "(radars give object lists only)"
        )
