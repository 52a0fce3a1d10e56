"""Throttle/brake longitudinal model for the simulator: pedals in, acceleration out (lateral part reused).

Drive: the motor's force falls linearly from full at rest to none at ``top_speed_mps`` (a series DC
motor's torque-speed line, as on golf-cart-class shuttles), scaled by the throttle after a first-order
lag. Brake: GEM's measured pedal-deceleration relation, a = exp((b - 0.90) / 0.28) (the inverse of its
published map; the only pedal data among the papers), after a first-order lag; so the twist controller's
open-loop brake is exact here up to the lag, rolling resistance and drag, which it must still close
with its speed loop. Rolling resistance and aerodynamic drag act on top. Steering and the pose come from
the kinematic bicycle of ``sim.vehicle_model``.

Wired: ``sim.simulation`` moves the ego vehicle with this plant on every command that carries pedal
positions (``ActuatorCommand.throttle`` / ``brake``, which ``longitudinal_controller = "gem_twist"``
sends); commands without pedals (the operator's brake, the safety's own brake when the software is
silent) use the acceleration model on the same vehicle state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.pedal_map import brake_decel_mps2
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState

__all__ = ["ThrottleBrakeDynamics", "ThrottleBrakeVehicle", "brake_decel_mps2"]


@dataclass(frozen=True, slots=True, kw_only=True)
class ThrottleBrakeDynamics:
    """Pedal plant parameters.

    Attributes:
        full_throttle_accel_mps2: acceleration at full throttle from rest; None takes the vehicle's
            maximum acceleration.
        top_speed_mps: speed at which the motor's force reaches zero; None is 1.2x the vehicle's top speed.
        throttle_lag_s, brake_lag_s: first-order lags of the drive and the brake.
        brake_log_gain, brake_offset: GEM's map b = gain ln(a) + offset, inverted.
        rolling_decel_mps2: rolling resistance (as ``ActuatorDynamics``).
        drag_per_m: aerodynamic drag over mass, a = drag_per_m * v^2 (0.5 rho C_d A / m; 1.2 kg/m^3,
            C_d A = 1.5 m^2 and 1500 kg give 6e-4).
        steering: the steering's lag and the emergency brake's deceleration.
    """

    full_throttle_accel_mps2: float | None = None
    top_speed_mps: float | None = None
    throttle_lag_s: float = 0.25
    brake_lag_s: float = 0.15
    brake_log_gain: float = 0.28
    brake_offset: float = 0.90
    rolling_decel_mps2: float = 0.05
    drag_per_m: float = 6e-4
    steering: ActuatorDynamics = field(default_factory=ActuatorDynamics)

    def __post_init__(self) -> None:
        for name in ("throttle_lag_s", "brake_lag_s", "brake_log_gain"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"ThrottleBrakeDynamics.{name}: expected a positive number, got {value}")


class ThrottleBrakeVehicle:
    """The shuttle driven by pedals: ``step(dt, throttle, brake, steer_front, steer_rear, emergency)``."""

    def __init__(
        self, geometry: VehicleGeometry, dynamics: ThrottleBrakeDynamics, state: VehicleState
    ) -> None:
        self.geometry = geometry
        self.dynamics = dynamics
        self.full_throttle_mps2 = (
            geometry.max_accel_mps2
            if dynamics.full_throttle_accel_mps2 is None
            else dynamics.full_throttle_accel_mps2
        )
        self.top_speed_mps = (
            1.2 * geometry.max_speed_mps if dynamics.top_speed_mps is None else dynamics.top_speed_mps
        )
        # The bicycle integrates the pose and the steering; the acceleration reaches it without its own lag
        # (the pedal lags are here) and without its rolling resistance (applied here too).
        body = ActuatorDynamics(
            accel_lag_s=1e-9,
            steer_lag_s=dynamics.steering.steer_lag_s,
            emergency_decel_mps2=dynamics.steering.emergency_decel_mps2,
            rolling_decel_mps2=0.0,
        )
        self.bicycle = KinematicBicycle(geometry, body, state)
        self.throttle = 0.0
        self.brake = 0.0

    @property
    def state(self) -> VehicleState:
        return self.bicycle.state

    def step(
        self,
        dt_s: float,
        throttle: float,
        brake: float,
        steer_front_cmd_rad: float,
        steer_rear_cmd_rad: float,
        emergency_brake: bool,
    ) -> None:
        """Advance by ``dt_s``; pedals are clipped to [0, 1]."""
        if not (math.isfinite(throttle) and math.isfinite(brake)):
            raise MessageError(f"ThrottleBrakeVehicle.step: expected finite pedals, got {throttle}, {brake}")
        d = self.dynamics
        self.throttle += (min(max(throttle, 0.0), 1.0) - self.throttle) * min(1.0, dt_s / d.throttle_lag_s)
        self.brake += (min(max(brake, 0.0), 1.0) - self.brake) * min(1.0, dt_s / d.brake_lag_s)
        v = self.state.speed_mps
        drive = self.throttle * self.full_throttle_mps2 * max(0.0, 1.0 - v / self.top_speed_mps)
        resist = brake_decel_mps2(self.brake, d.brake_log_gain, d.brake_offset) + d.drag_per_m * v * v
        if v > 0.0:
            resist += d.rolling_decel_mps2
        elif drive <= resist:
            # At rest the brakes and friction hold; they never push the vehicle backwards.
            resist = drive
        self.bicycle.step(dt_s, drive - resist, steer_front_cmd_rad, steer_rear_cmd_rad, emergency_brake)
