"""What the reliability monitor watches and its thresholds: sensor streams, fail-safe levels, limits."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from lastmile.core.errors import ConfigError
from lastmile.core.safety_messages import FailSafeLevel, MalfunctionKind

K = MalfunctionKind
L = FailSafeLevel

DEFAULT_LEVELS: dict[MalfunctionKind, FailSafeLevel] = {
    K.SENSOR_SILENT: L.MINIMAL_RISK_MANOEUVRE,
    K.SENSOR_RATE_LOW: L.SPEED_LIMIT,
    K.SENSOR_FROZEN: L.MINIMAL_RISK_MANOEUVRE,
    K.SENSOR_GARBAGE: L.MINIMAL_RISK_MANOEUVRE,
    K.SENSOR_BLOCKAGE: L.MINIMAL_RISK_MANOEUVRE,
    K.SENSOR_NOISE: L.SPEED_LIMIT,
    K.SENSOR_LATENCY: L.SPEED_LIMIT,
    K.SENSOR_OUT_OF_ORDER: L.SPEED_LIMIT,
    K.OFF_MAP: L.EMERGENCY_STOP,
    K.OFF_ROUTE: L.MINIMAL_RISK_MANOEUVRE,
    K.WEATHER_VISIBILITY: L.MINIMAL_RISK_MANOEUVRE,
    K.WEATHER_PRECIPITATION: L.TAKEOVER_REQUEST,
    K.LOCALIZATION_INVALID: L.EMERGENCY_STOP,
    K.LOCALIZATION_COVARIANCE: L.SPEED_LIMIT,
    K.GNSS_LOST: L.SPEED_LIMIT,
    K.LOCALIZATION_DEAD_RECKONING: L.SPEED_LIMIT,
    K.LOCALIZATION_GATE_REJECTIONS: L.SPEED_LIMIT,
}
"""Fail-safe level of each malfunction at its out-of-ODD threshold (degraded thresholds ask SPEED_LIMIT).

Why: losing the pose (invalid, or off the drivable area) means the vehicle cannot stay in the drivable
area, the one hazard ISO 22737 answers with an immediate stop; losing a sensor, a frozen or garbage
stream or a blocked view leaves the pose and the other sensors, enough for a comfortable stop; a poor
but usable input (rate, latency, noise, covariance: Snow Lion's 0.5 m/s) only slows the shuttle; a
lost GNSS fix with the pose dead-reckoning holds it at Snow Lion's 0.5 m/s (and at standstill once it
stopped: it never re-accelerates on dead reckoning), and once the position's protection level exceeds
the lane margin the vehicle stops by the minimal risk manoeuvre (``LOCALIZATION_COVARIANCE``); a pose
held by landmarks needs no GNSS; heavy precipitation is for the operator to judge.
"""


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorSpec:
    """One watched sensor stream.

    Attributes:
        key: stream key as :func:`lastmile.safety.frame_checks.sensor_key` names it ("gnss", "imu",
            "odom", "door", a radar, LiDAR or camera id).
        rate_hz: expected frame rate, > 0.
        max_latency_us: arrival minus capture stamp above this is a latency spike.
        frozen_after: this many identical payloads in a row mean a frozen driver (None: not checked, for
            streams that legitimately repeat, such as door state or odometry at standstill). A freeze is
            seen ``(frozen_after - 1)`` periods after it starts: keep that within one period + 100 ms.
        min_points: a LiDAR sweep with fewer points, or a radar cycle with fewer raw reflections
            (``RadarFrame.raw_detections``, clutter included), is blocked (0: not checked).
        silent_level, frozen_level: override the default levels for this stream (a rear radar matters
            less than the front LiDAR); None keeps :data:`DEFAULT_LEVELS`.
    """

    key: str
    rate_hz: float
    max_latency_us: int = 300_000
    frozen_after: int | None = 3
    min_points: int = 0
    silent_level: FailSafeLevel | None = None
    frozen_level: FailSafeLevel | None = None

    def __post_init__(self) -> None:
        if not self.rate_hz > 0 or self.max_latency_us <= 0:
            raise ConfigError(
                f"SensorSpec {self.key!r}: expected rate_hz > 0 and max_latency_us > 0, got "
                f"{self.rate_hz}, {self.max_latency_us}"
            )
        if self.frozen_after is not None and self.frozen_after < 2:
            raise ConfigError(
                f"SensorSpec {self.key!r}: expected frozen_after >= 2 or None, got {self.frozen_after}"
            )

    @property
    def period_us(self) -> int:
        return round(1e6 / self.rate_hz)


def default_sensor_specs(
    radar_keys: tuple[str, str] = ("radar_front", "radar_rear"),
) -> tuple[SensorSpec, ...]:
    """The simulator's default suite (sim/sensors.py): GNSS 10 Hz, IMU and odometry 50 Hz, radars 20 Hz.

    Args:
        radar_keys: the front and rear radars' sensor ids (the simulator calls them "front", "rear").
    """
    front, rear = radar_keys
    return (
        SensorSpec(key="gnss", rate_hz=10.0),
        SensorSpec(key="imu", rate_hz=50.0, frozen_after=5),
        # Odometry carries an alive counter: one repeat is a frozen gateway, even at standstill.
        SensorSpec(key="odom", rate_hz=50.0, frozen_after=2),
        SensorSpec(key="door", rate_hz=10.0, frozen_after=None, silent_level=FailSafeLevel.TAKEOVER_REQUEST),
        # Radars send a cycle counter: one repeated list is already a frozen driver. A cycle without a
        # single raw reflection (not even the road's clutter) is a blocked radome.
        SensorSpec(key=front, rate_hz=20.0, frozen_after=2, min_points=1),
        SensorSpec(
            key=rear, rate_hz=20.0, frozen_after=2, min_points=1, silent_level=FailSafeLevel.SPEED_LIMIT
        ),
    )


def raw_sensor_specs(lidar_ids: tuple[str, ...], camera_ids: tuple[str, ...]) -> tuple[SensorSpec, ...]:
    """LiDAR and camera streams of the raw-sensor rig (10 Hz each), keyed as
    :func:`lastmile.safety.frame_checks.sensor_key` does.

    A LiDAR never repeats a sweep point for point, so two equal ones are a frozen driver; one with
    fewer than 500 returns is blocked (a 16-channel unit gives thousands even in fog). A camera's box
    list may repeat (an empty road), so it is not checked for freezing, and losing one leaves the LiDAR
    to detect: a speed limit, not a manoeuvre.
    """
    return (
        *(SensorSpec(key=f"lidar_{i}", rate_hz=10.0, frozen_after=2, min_points=500) for i in lidar_ids),
        *(
            SensorSpec(
                key=f"camera_{i}", rate_hz=10.0, frozen_after=None, silent_level=FailSafeLevel.SPEED_LIMIT
            )
            for i in camera_ids
        ),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class ReliabilityConfig:
    """Thresholds of the reliability monitor (units in the names).

    Attributes:
        sensors: watched streams.
        levels: fail-safe level per malfunction kind (missing kinds use :data:`DEFAULT_LEVELS`).
        silent_factor, silent_margin_us: a stream is silent after ``factor * period + margin`` without a
            frame (defaults detect a dead sensor within one period + 80 ms, + one check period).
        rate_window_us, min_rate_fraction: measured rate over the window below ``fraction * rate_hz``.
        event_hold_us: a one-off event (garbage frame, latency spike, out-of-order stamp) stays active
            this long.
        overdue_margin_us: a stream's next frame is overdue (SENSOR_LATENCY) this long after one period
            past its last stamp plus the lowest latency the stream has shown.
        out_of_order_max: more stamps going backwards within ``rate_window_us`` than this is a fault.
            One sensor's stream travels one link in order, so by default a single step back is one.
        blockage_max, noise_max: perception's blockage fraction / noise level above these.
        visibility_degraded_m, visibility_min_m: below the first, speed limit; below the second, out of ODD.
        precipitation_degraded_mmph, precipitation_max_mmph: the same for precipitation.
        weather_speed_cap_mps: cap in degraded weather.
        route_offset_max_m: the pose farther than this from the route centre line is off route.
        pos_std_degraded_m, pos_std_max_m: localization std above the first: speed limit
            (Snow Lion's forced 0.5 m/s); above the second: the MRM.
        covariance_speed_cap_mps: that cap, also while the pose dead-reckons (no absolute correction).
        protection_sigma_factor: the position's protection level is this many sigma of its largest
            axis (1.96: a two-sided 95 % bound on the lateral error).
        lane_margin_m: room between the vehicle's side and its lane's edge where the monitor has no
            map margin of its own (None: only the map's, or none); a protection level beyond the margin
            is the MRM (Reid et al. 2019, "Localization requirements for autonomous vehicles": the
            lateral alert limit is half the lane width less half the vehicle width).
        standstill_mps: below this the vehicle counts as stopped (dead reckoning holds it there).
        gnss_lost_us: no usable GNSS fix for this long.
        gate_rejections_max, gate_window_us: more EKF gate rejections than this within the window.
        gross_rejections_max: more gross rejections (``PoseEkf.gross_rejections``: a fix 20 sigma off)
            than this within the window; 0: the first one is a fault, answered within one GNSS period.
        startup_grace_us: checks of things never seen (a stream, a valid pose) start after this.
    """

    sensors: tuple[SensorSpec, ...] = field(default_factory=default_sensor_specs)
    levels: Mapping[MalfunctionKind, FailSafeLevel] = field(default_factory=dict)
    silent_factor: float = 1.0
    silent_margin_us: int = 80_000
    rate_window_us: int = 2_000_000
    min_rate_fraction: float = 0.6
    event_hold_us: int = 1_000_000
    overdue_margin_us: int = 30_000
    out_of_order_max: int = 0
    blockage_max: float = 0.3
    noise_max: float = 0.25
    visibility_degraded_m: float = 150.0
    visibility_min_m: float = 50.0
    precipitation_degraded_mmph: float = 4.0
    precipitation_max_mmph: float = 16.0
    weather_speed_cap_mps: float = 2.5
    route_offset_max_m: float = 5.0
    pos_std_degraded_m: float = 0.3
    pos_std_max_m: float = 1.0
    covariance_speed_cap_mps: float = 0.5
    protection_sigma_factor: float = 1.96
    lane_margin_m: float | None = None
    standstill_mps: float = 0.05
    gnss_lost_us: int = 2_000_000
    gate_rejections_max: int = 1
    gate_window_us: int = 2_000_000
    gross_rejections_max: int = 0
    startup_grace_us: int = 2_000_000

    def __post_init__(self) -> None:
        keys = [s.key for s in self.sensors]
        if len(set(keys)) != len(keys):
            raise ConfigError(f"ReliabilityConfig.sensors: expected unique keys, got {keys}")
        if not (self.visibility_min_m < self.visibility_degraded_m):
            raise ConfigError(
                "ReliabilityConfig: expected visibility_min_m < visibility_degraded_m, got "
                f"{self.visibility_min_m} >= {self.visibility_degraded_m}"
            )
        if not (self.precipitation_degraded_mmph < self.precipitation_max_mmph):
            raise ConfigError(
                "ReliabilityConfig: expected precipitation_degraded_mmph < precipitation_max_mmph, got "
                f"{self.precipitation_degraded_mmph} >= {self.precipitation_max_mmph}"
            )
        if not (self.pos_std_degraded_m < self.pos_std_max_m):
            raise ConfigError(
                "ReliabilityConfig: expected pos_std_degraded_m < pos_std_max_m, got "
                f"{self.pos_std_degraded_m} >= {self.pos_std_max_m}"
            )
        if not 0.0 < self.min_rate_fraction < 1.0:
            raise ConfigError(
                f"ReliabilityConfig.min_rate_fraction: expected in (0, 1), got {self.min_rate_fraction}"
            )
        if not self.protection_sigma_factor > 0 or (
            self.lane_margin_m is not None and self.lane_margin_m < 0
        ):
            raise ConfigError(
                "ReliabilityConfig: expected protection_sigma_factor > 0 and lane_margin_m >= 0 or None, got "
                f"{self.protection_sigma_factor} and {self.lane_margin_m}"
            )
        if self.gate_rejections_max < 0 or self.gross_rejections_max < 0:
            raise ConfigError(
                "ReliabilityConfig: expected gate_rejections_max and gross_rejections_max >= 0, got "
                f"{self.gate_rejections_max} and {self.gross_rejections_max}"
            )

    def level(self, kind: MalfunctionKind) -> FailSafeLevel:
        return self.levels.get(kind, DEFAULT_LEVELS[kind])
