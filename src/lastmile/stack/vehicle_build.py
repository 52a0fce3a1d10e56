"""The vehicle, composed: its software (the stack) and, beside it, its safety (supervisor, gate, watchdog).

The runner reaches the vehicle only through here and :mod:`lastmile.core`: it hands over the map's
s-layers, the vehicle's geometry, the sensors' calibration and the run configuration's stack settings,
and gets back two objects it drives through their interfaces.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.geometry import SE2
from lastmile.core.safety_messages import FailSafeLevel
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.perception.late_fusion import LateFusionConfig
from lastmile.safety.failsafe import FailSafeArbiter, FailSafeConfig
from lastmile.safety.hardware_watchdog import HardwareWatchdog, HardwareWatchdogConfig
from lastmile.safety.health_monitor import HealthMonitor, ModuleSpec
from lastmile.safety.lane_margin import lane_margin_along_route
from lastmile.safety.reliability_config import ReliabilityConfig, raw_sensor_specs
from lastmile.safety.reliability_monitor import ReliabilityMonitor
from lastmile.safety.supervisor import SafetySupervisor
from lastmile.safety.vehicle_safety import VehicleSafety
from lastmile.stack.raw_perception import RawPerceptionConfig
from lastmile.stack.shuttle_stack import (
    DEFAULT_SENSORS,
    MODULE_PERIODS_US,
    ModuleFaultHook,
    ShuttleStack,
    StackConfig,
)
from lastmile.stack.stack_settings import StackSettings

# Losing the pose or the actuation loop leaves nothing to stop comfortably with: an e-stop. Any other
# module failing still leaves pose and control for a minimal risk manoeuvre.
MODULE_FAILURE_LEVEL = {"localization": FailSafeLevel.EMERGENCY_STOP, "control": FailSafeLevel.EMERGENCY_STOP}


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorCalibration:
    """Where the vehicle's sensors sit, as a real vehicle's software is configured with them.

    Attributes:
        radar_mounts: base_from_sensor pose of each radar by sensor id.
        lidar_mounts: (4, 4) base_from_sensor of each LiDAR by sensor id.
        cameras: the cameras whose boxes raw perception fuses.
        light_cameras: the cameras whose traffic-light detections the stack receives.
    """

    radar_mounts: dict[str, SE2] = field(default_factory=dict)
    lidar_mounts: dict[str, np.ndarray] = field(default_factory=dict)
    cameras: tuple[PinholeCamera, ...] = ()
    light_cameras: tuple[PinholeCamera, ...] = ()


@dataclass(frozen=True, slots=True)
class Vehicle:
    """The vehicle software and the vehicle safety that runs apart from it."""

    software: ShuttleStack
    safety: VehicleSafety


def stack_config(settings: StackSettings, calibration: SensorCalibration, tick_us: int) -> StackConfig:
    """The stack's own configuration from the run configuration's settings and the calibration."""
    decision = settings.decision
    if settings.cruise_speed_mps is not None:
        decision = dataclasses.replace(decision, cruise_speed_mps=settings.cruise_speed_mps)
    raw = settings.perception.needs_raw_sensors
    camera_ids = tuple(c.camera_id for c in calibration.cameras)
    return StackConfig(
        tick_us=tick_us,
        lateral_controller=settings.lateral_controller,
        longitudinal_controller=settings.longitudinal_controller,
        planner=settings.planner,
        speed_planner=settings.speed_planner,
        speed_planning=settings.speed_planning,
        radar_mounts=calibration.radar_mounts,
        light_cameras=calibration.light_cameras,
        serve_all_stops=settings.serve_all_stops,
        decision=decision,
        path=settings.path,
        longitudinal=settings.longitudinal,
        lateral=settings.lateral,
        ekf=settings.ekf,
        inertial_ekf=settings.inertial_ekf,
        landmarks=settings.landmarks,
        scan_matching=settings.scan_matching,
        amcl=settings.amcl,
        localization=settings.localization,
        perception_mode=settings.perception,
        lidar_mounts=calibration.lidar_mounts if raw else {},
        cameras=calibration.cameras if raw else (),
        raw_perception=RawPerceptionConfig(
            detector=settings.lidar_detector,
            fusion=LateFusionConfig(pedestrian_verification=settings.pedestrian_verification),
        ),
        occupancy_stop=settings.occupancy_stop,
        nus_speed=settings.nus_speed,
        gem_sign_stop=settings.gem_sign_stop,
        reliability=ReliabilityConfig(
            sensors=DEFAULT_SENSORS
            + (raw_sensor_specs(tuple(calibration.lidar_mounts), camera_ids) if raw else ())
        ),
    )


def build_vehicle(
    layers: SLayerDatabase,
    geometry: VehicleGeometry,
    settings: StackSettings,
    calibration: SensorCalibration,
    tick_us: int,
    fault_hook: ModuleFaultHook | None = None,
) -> Vehicle:
    """The stack for ``settings`` and its vehicle safety, watching the same map, route and sensors."""
    config = stack_config(settings, calibration, tick_us)
    software = ShuttleStack(layers, geometry, config, fault_hook=fault_hook)
    safety = build_safety(
        layers,
        config.reliability,
        settings.safety.failsafe(),
        settings.safety.watchdog(),
        vehicle_width_m=geometry.width_m,
    )
    return Vehicle(software=software, safety=safety)


def build_safety(
    layers: SLayerDatabase,
    reliability: ReliabilityConfig,
    failsafe: FailSafeConfig | None = None,
    watchdog: HardwareWatchdogConfig | None = None,
    vehicle_width_m: float | None = None,
) -> VehicleSafety:
    """The vehicle safety watching the stack's modules (:data:`MODULE_PERIODS_US`), the sensors of
    ``reliability`` and the map's route, arbitrating with ``failsafe``; with ``vehicle_width_m`` it
    also holds the pose's protection level to the lane margin along the route."""
    margin = lane_margin_along_route(layers, vehicle_width_m) if vehicle_width_m is not None else None
    supervisor = SafetySupervisor(
        HealthMonitor(
            [
                ModuleSpec(
                    name=name,
                    period_us=period,
                    failure_level=MODULE_FAILURE_LEVEL.get(name, FailSafeLevel.MINIMAL_RISK_MANOEUVRE),
                )
                for name, period in MODULE_PERIODS_US.items()
            ]
        ),
        ReliabilityMonitor(reliability, layers.hdmap, layers.centerline, lane_margin_m=margin),
        FailSafeArbiter(config=failsafe, layers=layers),
    )
    return VehicleSafety(supervisor, HardwareWatchdog(watchdog))
