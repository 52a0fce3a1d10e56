"""Actuator-lag compensation for a lateral law without preview: where the body will be when the wheels answer.

A law that looks only at the present pose (Stanley's front axle, eq. 2 of aUToronto) commands a wheel
angle the steer-by-wire reaches about one time constant later, plus the command's own low-pass filter.
Over that time the body keeps turning on the wheels it has, so the law reacts late and overshoots every
turn-in. The compensation is the usual one for a known actuator delay (a Smith-predictor-like state
prediction): an internal model of the steering (the same first-order lag and rate limit) estimates the
wheel angle from the commands sent, the kinematic bicycle carries the pose forward over the delay with
that angle moving toward the last command, and the law is evaluated at the predicted pose. Nothing is
fitted: the horizon is the actuator's time constant plus the filter's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.vehicle import STEER_LAG_S

SHUTTLE_STEER_LAG_S = STEER_LAG_S
"""The shuttle's steer-by-wire time constant (``core.vehicle.STEER_LAG_S``, which the simulator's
``ActuatorDynamics.steer_lag_s`` also takes)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SteeringLagModel:
    """The steer-by-wire as the controller models it.

    Attributes:
        lag_s: first-order time constant of the wheel angle's answer to the command (s); 0 turns the
            compensation off.
        max_rate_radps: the actuator's steering rate limit (rad/s).
        substep_s: integration step of the prediction (s).
    """

    lag_s: float
    max_rate_radps: float
    substep_s: float = 0.01

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lag_s) and self.lag_s >= 0.0):
            raise ConfigError(f"SteeringLagModel.lag_s: expected a finite number >= 0 s, got {self.lag_s}")
        if not (self.max_rate_radps > 0.0 and self.substep_s > 0.0):
            raise ConfigError(
                f"SteeringLagModel: expected max_rate_radps > 0 and substep_s > 0, "
                f"got {self.max_rate_radps} and {self.substep_s}"
            )


def lag_step_rad(current_rad: float, command_rad: float, dt_s: float, model: SteeringLagModel) -> float:
    """The wheel angle after ``dt_s`` of a first-order lag toward ``command_rad``, rate-limited."""
    if model.lag_s == 0.0:
        return command_rad
    step = (command_rad - current_rad) * (1.0 - math.exp(-dt_s / model.lag_s))
    limit = model.max_rate_radps * dt_s
    return current_rad + min(max(step, -limit), limit)


class LagPredictor:
    """Tracks the wheel angle the commands produce and predicts the pose one actuator delay ahead."""

    def __init__(self, model: SteeringLagModel, wheelbase_m: float, horizon_s: float) -> None:
        if not (math.isfinite(horizon_s) and horizon_s >= 0.0):
            raise ConfigError(f"LagPredictor.horizon_s: expected a finite number >= 0 s, got {horizon_s}")
        self.model = model
        self.wheelbase_m = wheelbase_m
        self.horizon_s = horizon_s
        self.wheel_rad = 0.0  # the modelled front wheel angle
        self._command_rad = 0.0  # the last command sent

    def reset(self) -> None:
        self.wheel_rad = 0.0
        self._command_rad = 0.0

    def advance(self, dt_s: float) -> None:
        """The wheel angle after the last command was held for ``dt_s`` (call once per control step)."""
        self.wheel_rad = lag_step_rad(self.wheel_rad, self._command_rad, dt_s, self.model)

    def sent(self, command_rad: float) -> None:
        """Record the command just sent to the actuator."""
        self._command_rad = command_rad

    def predict(self, pose: SE2, speed_mps: float, all_wheel: bool) -> SE2:
        """The rear-axle pose ``horizon_s`` ahead: kinematic bicycle at the present speed, the modelled
        wheel angle moving toward the last command (rear = -front with all-wheel steer)."""
        if self.horizon_s == 0.0 or speed_mps <= 0.0:
            return pose
        n = max(1, math.ceil(self.horizon_s / self.model.substep_s - 1e-9))
        dt = self.horizon_s / n
        wheel, half = self.wheel_rad, self.wheelbase_m / 2.0
        x, y, yaw = pose.x_m, pose.y_m, pose.yaw_rad
        for _ in range(n):
            wheel = lag_step_rad(wheel, self._command_rad, dt, self.model)
            tan_f = math.tan(wheel)
            tan_r = -tan_f if all_wheel else 0.0
            beta = math.atan((tan_f + tan_r) / 2.0)
            yaw_rate = speed_mps * math.cos(beta) * (tan_f - tan_r) / self.wheelbase_m
            # Integrate the centre of the wheelbase (its velocity is at beta to the body axis).
            cx = x + half * math.cos(yaw) + speed_mps * math.cos(yaw + beta) * dt
            cy = y + half * math.sin(yaw) + speed_mps * math.sin(yaw + beta) * dt
            yaw = wrap_angle_rad(yaw + yaw_rate * dt)
            x, y = cx - half * math.cos(yaw), cy - half * math.sin(yaw)
        return SE2(x, y, yaw)
