"""Safety messages: fail-safe levels, malfunction signals, system health and the safety directive."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum, IntEnum

from lastmile.core.errors import MessageError
from lastmile.core.stamp import Stamp


class FailSafeLevel(IntEnum):
    """Fail-safe responses by priority (a larger value wins the arbitration)."""

    NONE = 0
    SPEED_LIMIT = 1
    TAKEOVER_REQUEST = 2
    MINIMAL_RISK_MANOEUVRE = 3
    EMERGENCY_STOP = 4


class MalfunctionKind(Enum):
    """What a monitor found wrong; the default fail-safe level of each is in ``safety/README.md``."""

    MODULE_SILENT = "module_silent"
    MODULE_UNHEALTHY = "module_unhealthy"
    MODULE_EXCEPTION = "module_exception"
    SENSOR_SILENT = "sensor_silent"
    SENSOR_RATE_LOW = "sensor_rate_low"
    SENSOR_FROZEN = "sensor_frozen"
    SENSOR_GARBAGE = "sensor_garbage"
    SENSOR_BLOCKAGE = "sensor_blockage"
    SENSOR_NOISE = "sensor_noise"
    SENSOR_LATENCY = "sensor_latency"
    SENSOR_OUT_OF_ORDER = "sensor_out_of_order"
    OFF_MAP = "off_map"
    OFF_ROUTE = "off_route"
    WEATHER_VISIBILITY = "weather_visibility"
    WEATHER_PRECIPITATION = "weather_precipitation"
    LOCALIZATION_INVALID = "localization_invalid"
    LOCALIZATION_COVARIANCE = "localization_covariance"
    GNSS_LOST = "gnss_lost"
    LOCALIZATION_DEAD_RECKONING = "localization_dead_reckoning"
    """The pose has had no absolute correction (GNSS, landmarks) for the mode's timeout."""
    LOCALIZATION_GATE_REJECTIONS = "localization_gate_rejections"
    OPERATOR_ESTOP = "operator_estop"
    STACK_FAILED = "stack_failed"
    """The vehicle software as a whole raised, or returned no command, on a tick."""


class OperatorAction(Enum):
    """What the operator (on board or remote) tells the vehicle's safety."""

    EMERGENCY_STOP = "emergency_stop"
    """The e-stop button: EMERGENCY_STOP until a reset."""
    RESET = "reset"
    """Release of the e-stop, confirming the cause is gone (also sent when a safety driver hands back)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class OperatorInput:
    """An operator's input, delivered to the vehicle like a sensor frame (the vehicle's safety reads it).

    Attributes:
        action: what the operator did.
        reason: what the operator gave as the cause (logged with the e-stop).
    """

    stamp: Stamp
    action: OperatorAction
    reason: str = ""

    def validate(self) -> None:
        if not isinstance(self.action, OperatorAction):
            raise MessageError(f"OperatorInput.action: expected an OperatorAction, got {self.action!r}")


class MrmKind(Enum):
    """How a minimal risk manoeuvre ends (ISO 22737's minimal risk condition)."""

    NONE = "none"
    STOP_IN_LANE = "stop_in_lane"
    PULL_OVER = "pull_over"


@dataclass(frozen=True, slots=True, kw_only=True)
class MalfunctionSignal:
    """One active malfunction, with the fail-safe level it asks for.

    Attributes:
        source: what is affected ("module:planning", "sensor:radar_front", "localization", "odd").
        kind: what is wrong.
        level: the fail-safe response it asks for.
        reason: human-readable detail (values and thresholds), logged and shown to the operator.
        speed_cap_mps: for SPEED_LIMIT (and above), the speed it allows; None: no cap of its own.
    """

    stamp: Stamp
    source: str
    kind: MalfunctionKind
    level: FailSafeLevel
    reason: str
    speed_cap_mps: float | None = None

    def validate(self) -> None:
        if self.speed_cap_mps is not None and not (
            math.isfinite(self.speed_cap_mps) and self.speed_cap_mps >= 0.0
        ):
            raise MessageError(
                f"MalfunctionSignal.speed_cap_mps: expected None or a finite number >= 0, "
                f"got {self.speed_cap_mps}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class ModuleHealth:
    """The process-health monitor's view of one module.

    Attributes:
        last_beat_us: stamp of the module's last heartbeat (-1: never heard from).
        silent: the watchdog expired (no heartbeat within the module's timeout).
    """

    module: str
    healthy: bool
    reason: str
    last_beat_us: int
    silent: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class SystemHealth:
    """Aggregate health: healthy only if every watched module is (aUToronto's system health message)."""

    stamp: Stamp
    healthy: bool
    modules: tuple[ModuleHealth, ...] = field(default_factory=tuple)

    def unhealthy(self) -> tuple[ModuleHealth, ...]:
        return tuple(m for m in self.modules if not m.healthy)


@dataclass(frozen=True, slots=True, kw_only=True)
class WeatherReport:
    """Conditions as perceived on board (perception's estimate or a weather station over V2I).

    Attributes:
        visibility_m: meteorological visibility, > 0.
        precipitation_mmph: precipitation rate, >= 0 (rain or water-equivalent snow).
        source: who estimated it ("perception", "v2i_station").
    """

    stamp: Stamp
    visibility_m: float
    precipitation_mmph: float
    source: str = "perception"

    def validate(self) -> None:
        if not (math.isfinite(self.visibility_m) and self.visibility_m > 0.0):
            raise MessageError(
                f"WeatherReport.visibility_m: expected a finite number > 0, got {self.visibility_m}"
            )
        if not (math.isfinite(self.precipitation_mmph) and self.precipitation_mmph >= 0.0):
            raise MessageError(
                "WeatherReport.precipitation_mmph: expected a finite number >= 0, "
                f"got {self.precipitation_mmph}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorDiagnostics:
    """Perception's per-sensor quality estimate (blockage and noise cannot be seen from rates alone).

    Attributes:
        sensor_id: the sensor ("lidar_top", "radar_front", "camera_front").
        blockage_fraction: share of the field of view that returns nothing or a wall at < 0.5 m, [0, 1].
        noise_level: share of returns classified as noise (rain, snow, spray, false alarms), [0, 1].
    """

    stamp: Stamp
    sensor_id: str
    blockage_fraction: float
    noise_level: float

    def validate(self) -> None:
        for name in ("blockage_fraction", "noise_level"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise MessageError(f"SensorDiagnostics.{name}: expected a number in [0, 1], got {value}")


@dataclass(frozen=True, slots=True, kw_only=True)
class SafetyDirective:
    """What the fail-safe arbitration orders decision and control to obey (and the actuator gate enforces).

    Attributes:
        level: the latched fail-safe level.
        speed_cap_mps: the speed decision/control must not exceed (None: no cap).
        mrm: how the minimal risk manoeuvre ends (NONE below MINIMAL_RISK_MANOEUVRE).
        mrm_decel_mps2: deceleration, > 0, the manoeuvre uses (comfortable; the e-stop uses the maximum).
        mrm_stop_s_m: route s where the front bumper should come to rest for STOP_IN_LANE / PULL_OVER
            (None if unknown, e.g. without localization: then just brake at ``mrm_decel_mps2``).
        emergency_stop: brake at the maximum deceleration now (EMERGENCY_STOP).
        takeover_request: ask the operator to take over (TAKEOVER_REQUEST and above).
        since_us: when the current level was entered.
        reasons: the reasons of the signals that hold the current level, most severe first.
    """

    stamp: Stamp
    level: FailSafeLevel
    speed_cap_mps: float | None = None
    mrm: MrmKind = MrmKind.NONE
    mrm_decel_mps2: float = 1.0
    mrm_stop_s_m: float | None = None
    emergency_stop: bool = False
    takeover_request: bool = False
    since_us: int = 0
    reasons: tuple[str, ...] = ()

    def validate(self) -> None:
        if self.speed_cap_mps is not None and not (
            math.isfinite(self.speed_cap_mps) and self.speed_cap_mps >= 0
        ):
            raise MessageError(
                "SafetyDirective.speed_cap_mps: expected None or a finite number >= 0, "
                f"got {self.speed_cap_mps}"
            )
        if not (math.isfinite(self.mrm_decel_mps2) and self.mrm_decel_mps2 > 0):
            raise MessageError(
                f"SafetyDirective.mrm_decel_mps2: expected a finite number > 0, got {self.mrm_decel_mps2}"
            )
        if self.emergency_stop != (self.level == FailSafeLevel.EMERGENCY_STOP):
            raise MessageError(
                f"SafetyDirective: expected emergency_stop exactly at EMERGENCY_STOP, got "
                f"emergency_stop={self.emergency_stop} at {self.level.name}"
            )
        if (self.mrm != MrmKind.NONE) != (self.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE):
            raise MessageError(
                f"SafetyDirective: expected an MRM kind exactly at MINIMAL_RISK_MANOEUVRE and above, got "
                f"{self.mrm.name} at {self.level.name}"
            )
