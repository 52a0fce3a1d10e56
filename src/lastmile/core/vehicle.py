"""The shuttle's geometry and limits, and the protocol the simulator drives a vehicle's software by."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from lastmile.core.errors import ConfigError
from lastmile.core.safety_messages import SafetyDirective
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import StackOutput, VehicleReport

STEER_LAG_S = 0.15
"""First-order time constant of the shuttle's steer-by-wire (s), a typical electric power-steering servo:
the simulator's drive-by-wire answers with it, and Stanley's lag compensation predicts with it."""


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleGeometry:
    """Dimensions and actuator limits of the shuttle (defaults: a WATonoBus-sized electric shuttle).

    The reference point of every pose is the centre of the rear axle; with all-wheel steer it is the
    centre of the wheelbase that stays on the path, but poses still refer to the rear axle.
    """

    length_m: float = 4.6
    width_m: float = 2.0
    wheelbase_m: float = 2.9
    rear_overhang_m: float = 0.85
    max_steer_rad: float = 0.55
    max_steer_rate_radps: float = 0.8
    max_speed_mps: float = 20.0 / 3.6
    max_accel_mps2: float = 1.5
    max_decel_mps2: float = 5.0
    comfort_decel_mps2: float = 1.5
    all_wheel_steer: bool = True
    seats: int = 6

    def __post_init__(self) -> None:
        for name in (
            "length_m",
            "width_m",
            "wheelbase_m",
            "max_steer_rad",
            "max_speed_mps",
            "max_accel_mps2",
        ):
            value = getattr(self, name)
            if not value > 0:
                raise ConfigError(f"VehicleGeometry.{name}: expected a positive number, got {value}")
        if self.wheelbase_m + self.rear_overhang_m >= self.length_m:
            raise ConfigError(
                f"VehicleGeometry: expected wheelbase_m + rear_overhang_m < length_m, got "
                f"{self.wheelbase_m} + {self.rear_overhang_m} >= {self.length_m}"
            )

    @property
    def front_from_rear_axle_m(self) -> float:
        """Distance from the rear axle to the front bumper."""
        return self.length_m - self.rear_overhang_m


class VehicleSoftware(Protocol):
    """What the loop drives: anything that turns sensor frames into commands.

    ``frames`` holds the frames delivered at ``now`` (their latency elapsed), in delivery order, which
    need not be capture order. ``safety`` is the directive the vehicle's safety (which runs apart from
    the software, in the loop) issued on the previous tick: decision and control obey it; the safety's
    actuator gate enforces it whatever the software does.
    """

    def tick(
        self, now: Stamp, frames: Sequence[SensorFrame], safety: SafetyDirective | None = None
    ) -> StackOutput: ...

    def report(self) -> VehicleReport:
        """Compute time per module and the software's own counters over the run so far."""
        ...
