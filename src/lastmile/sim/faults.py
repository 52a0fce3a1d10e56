"""Fault injection: what goes wrong with sensors, GNSS, the map and the stack's modules, and when.

Each fault is declared in the scenario file with its start and duration. Sensor faults act on the
frames the sensor models capture, before their latency (as a failing sensor or a bad cable would);
module faults are read by the runner, which makes the named stack module hang or raise.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal

from lastmile.core import frame_kinds
from lastmile.core.config import check_range
from lastmile.core.errors import ConfigError
from lastmile.core.rng import component_rng
from lastmile.core.sensor_frames import GnssInsFrame, SensorFrame
from lastmile.sim.frame_corruption import blind, garbage, nan_values

FaultKind = Literal[
    "dropout",
    "frozen",
    "latency_spike",
    "out_of_order",
    "nan",
    "garbage",
    "blind",
    "gnss_outage",
    "gnss_multipath",
    "map_misalignment",
    "module_hang",
    "module_raise",
]
SENSOR_FAULTS = ("dropout", "frozen", "latency_spike", "out_of_order", "nan", "garbage", "blind")
GNSS_FAULTS = ("gnss_outage", "gnss_multipath")
MODULE_FAULTS = ("module_hang", "module_raise")
SCALAR_SENSORS = ("gnss", "imu", "odom")
SENSORS = ("gnss", "imu", "odom", "door", "radar_front", "radar_rear")
"""Sensor targets the simulator has today (LiDAR and camera targets join when those sensors do)."""
STACK_MODULES = ("localization", "tracking", "decision", "planning", "control")
FAULT_MENU: tuple[tuple[FaultKind, str], ...] = (
    ("dropout", "radar_front"),
    ("dropout", "radar_rear"),
    ("frozen", "radar_front"),
    ("latency_spike", "radar_front"),
    ("out_of_order", "radar_front"),
    ("garbage", "radar_front"),
    ("blind", "radar_front"),
    ("dropout", "gnss"),
    ("nan", "gnss"),
    ("nan", "imu"),
    ("nan", "odom"),
    ("garbage", "odom"),
    ("frozen", "odom"),
    ("gnss_outage", "gnss"),
    ("gnss_multipath", "gnss"),
    ("map_misalignment", "map"),
    ("module_hang", "planning"),
    ("module_raise", "tracking"),
)
"""Every fault kind on a representative target: what the suite and the generator inject."""


@dataclass(frozen=True, slots=True, kw_only=True)
class FaultSpec:
    """One injected fault.

    Attributes:
        kind: what goes wrong (see the module docstring and README for each kind's effect).
        target: a sensor ("gnss", "imu", "odom", "door", "radar_front", "radar_rear") for sensor
            faults, "gnss" for GNSS faults, "map" for a map misalignment, a stack module
            ("localization", "tracking", "decision", "planning", "control") for module faults.
        start_s, duration_s: when, in simulated seconds.
        latency_ms: extra latency of a latency spike.
        jitter_ms: out-of-order delivery holds each frame back by a random delay in
            [jitter_ms / 2, jitter_ms], so that later frames overtake it.
        offset_m: GNSS multipath error, or the map's misalignment, in metres.
    """

    kind: FaultKind
    target: str
    start_s: float
    duration_s: float
    latency_ms: float = 400.0
    jitter_ms: float = 250.0
    offset_m: float = 4.0

    def __post_init__(self) -> None:
        check_range("fault.start_s", self.start_s, 0.0, 24 * 3600.0)
        check_range("fault.duration_s", self.duration_s, 0.0, 24 * 3600.0)
        check_range("fault.latency_ms", self.latency_ms, 0.0, 60_000.0)
        check_range("fault.jitter_ms", self.jitter_ms, 0.0, 60_000.0)
        check_range("fault.offset_m", self.offset_m, 0.0, 1000.0)
        if self.kind in SENSOR_FAULTS:
            allowed: tuple[str, ...] = SCALAR_SENSORS if self.kind == "nan" else SENSORS
        elif self.kind in GNSS_FAULTS:
            allowed = ("gnss",)
        elif self.kind == "map_misalignment":
            allowed = ("map",)
        elif self.kind in MODULE_FAULTS:
            allowed = STACK_MODULES
        else:
            raise ConfigError(f"fault.kind: expected one of {FaultKind.__args__}, got {self.kind!r}")  # type: ignore[attr-defined]
        if self.target not in allowed:
            # NaN cannot travel in an array message (its constructor refuses it): use "garbage" there.
            raise ConfigError(f"fault.target for {self.kind}: expected one of {allowed}, got {self.target!r}")

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    def active(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.end_s


RAW_SENSOR_TARGET_PREFIXES = ("lidar_", "camera_")
"""Fault targets on the raw sensors (LiDARs, cameras): only the raw-sensor perception reads them."""


def sensor_of(frame: SensorFrame) -> str | None:
    """The fault target name of the sensor that captured ``frame`` (None: not a faultable sensor)."""
    return frame_kinds.sensor_name(frame)


class FaultInjector:
    """Applies the scenario's faults to captured frames; deterministic from the run's seed."""

    def __init__(self, faults: tuple[FaultSpec, ...], seed: int) -> None:
        self.faults = faults
        self._rng = component_rng(seed, "faults")
        self._frozen: dict[int, SensorFrame] = {}
        self._multipath_dir: dict[int, tuple[float, float]] = {}

    def capture(self, frame: SensorFrame, latency_us: int, t_s: float) -> list[tuple[SensorFrame, int]]:
        """What the sensor actually hands over for ``frame``: nothing, the frame changed, or it as is."""
        target = sensor_of(frame)
        if target is None:
            return [(frame, latency_us)]
        for index, f in enumerate(self.faults):
            if not f.active(t_s):
                self._frozen.pop(index, None)
                continue
            applies = (f.kind in SENSOR_FAULTS and f.target == target) or (
                target == "gnss" and (f.kind in GNSS_FAULTS or f.kind == "map_misalignment")
            )
            if applies:
                result = self._apply(index, f, frame, latency_us, t_s)
                if result is None:
                    return []
                frame, latency_us = result
        return [(frame, latency_us)]

    def module_fault(self, module: str, t_s: float) -> str | None:
        """ "hang" or "raise" when a module fault on ``module`` is active at ``t_s``, else None."""
        for f in self.faults:
            if f.kind in MODULE_FAULTS and f.target == module and f.active(t_s):
                return "hang" if f.kind == "module_hang" else "raise"
        return None

    # ------------------------------------------------------------------------------------------------
    def _apply(
        self, index: int, f: FaultSpec, frame: SensorFrame, latency_us: int, t_s: float
    ) -> tuple[SensorFrame, int] | None:
        rng = self._rng
        if f.kind == "dropout":
            return None
        if f.kind == "frozen":
            # The driver keeps publishing its last good payload under fresh stamps.
            held = self._frozen.setdefault(index, frame)
            return dataclasses.replace(held, stamp=frame.stamp), latency_us
        if f.kind == "latency_spike":
            return frame, latency_us + round(f.latency_ms * 1000.0)
        if f.kind == "out_of_order":
            # Held back between half and all of the jitter: later frames overtake it from the first
            # affected frame on. (A delay of a few ms would be no fault at all: nothing swaps.)
            return frame, latency_us + round(float(rng.uniform(0.5 * f.jitter_ms, f.jitter_ms)) * 1000.0)
        if f.kind == "blind":
            return blind(frame), latency_us
        if f.kind == "nan":
            return nan_values(frame), latency_us
        if f.kind == "garbage":
            return garbage(frame, rng), latency_us
        if not isinstance(frame, GnssInsFrame):
            return frame, latency_us
        if f.kind == "gnss_outage":
            # No fix: the receiver's dead-reckoned guess drifts and says so.
            drift_m = 0.5 * (t_s - f.start_s)
            return (
                dataclasses.replace(
                    frame,
                    x_m=frame.x_m + drift_m,
                    fix_ok=False,
                    pos_std_m=max(frame.pos_std_m, 1.0 + drift_m),
                ),
                latency_us,
            )
        if f.kind == "gnss_multipath":
            # Reflections: a jump of offset_m in a direction that changes every second, with a
            # receiver that still reports its usual small standard deviation (the dangerous case).
            second = int(t_s)
            key = index * 1_000_003 + second
            if key not in self._multipath_dir:
                angle = float(rng.uniform(-math.pi, math.pi))
                self._multipath_dir[key] = (math.cos(angle), math.sin(angle))
            ux, uy = self._multipath_dir[key]
            return (
                dataclasses.replace(frame, x_m=frame.x_m + f.offset_m * ux, y_m=frame.y_m + f.offset_m * uy),
                latency_us,
            )
        # map_misalignment: the map and the INS frame disagree by a constant offset (x east).
        return dataclasses.replace(frame, x_m=frame.x_m + f.offset_m), latency_us
