"""Kinematic bicycle with optional all-wheel steer, first-order actuator lag and limits."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.errors import MessageError
from lastmile.core.geometry import wrap_angle_rad
from lastmile.core.vehicle import STEER_LAG_S, VehicleGeometry


@dataclass(frozen=True, slots=True, kw_only=True)
class ActuatorDynamics:
    """How the drive-by-wire answers: first-order lags (s) and the emergency brake's deceleration."""

    accel_lag_s: float = 0.25
    steer_lag_s: float = STEER_LAG_S
    emergency_decel_mps2: float = 5.0
    # Rolling resistance brings a coasting shuttle to rest; it never rolls backwards on its own.
    rolling_decel_mps2: float = 0.05


@dataclass(slots=True)
class VehicleState:
    """Ground-truth state of the shuttle; (x_m, y_m) is the rear-axle centre, yaw from +x."""

    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float = 0.0
    accel_mps2: float = 0.0
    steer_front_rad: float = 0.0
    steer_rear_rad: float = 0.0
    yaw_rate_radps: float = 0.0


class KinematicBicycle:
    """Integrates the shuttle forward one tick at a time (explicit Euler at the base tick, 10 ms).

    With all-wheel steer the rear wheels turn opposite to the front (WATonoBus): the yaw rate doubles
    for a given wheel angle and the rear axle slips sideways, so the model integrates the centre of
    the wheelbase and derives the rear-axle pose from it.
    """

    def __init__(self, geometry: VehicleGeometry, dynamics: ActuatorDynamics, state: VehicleState) -> None:
        self.geometry = geometry
        self.dynamics = dynamics
        self.state = state

    def step(
        self,
        dt_s: float,
        accel_cmd_mps2: float,
        steer_front_cmd_rad: float,
        steer_rear_cmd_rad: float,
        emergency_brake: bool,
    ) -> None:
        """Advance by ``dt_s`` under the given commands (clamped to the actuator limits)."""
        if not (math.isfinite(accel_cmd_mps2) and math.isfinite(steer_front_cmd_rad)):
            raise MessageError(
                f"KinematicBicycle.step: expected finite commands, "
                f"got {accel_cmd_mps2}, {steer_front_cmd_rad}"
            )
        g, d, s = self.geometry, self.dynamics, self.state
        if emergency_brake:
            target_a = -d.emergency_decel_mps2
        else:
            target_a = min(max(accel_cmd_mps2, -g.max_decel_mps2), g.max_accel_mps2)
        s.accel_mps2 += (target_a - s.accel_mps2) * min(1.0, dt_s / d.accel_lag_s)
        max_rate = g.max_steer_rate_radps * dt_s
        for attr, cmd in (("steer_front_rad", steer_front_cmd_rad), ("steer_rear_rad", steer_rear_cmd_rad)):
            if attr == "steer_rear_rad" and not g.all_wheel_steer:
                cmd = 0.0
            cmd = min(max(cmd, -g.max_steer_rad), g.max_steer_rad)
            current = getattr(s, attr)
            step = (cmd - current) * min(1.0, dt_s / d.steer_lag_s)
            setattr(s, attr, current + min(max(step, -max_rate), max_rate))

        a = s.accel_mps2 - (d.rolling_decel_mps2 if s.speed_mps > 0 else 0.0)
        v_new = s.speed_mps + a * dt_s
        if v_new < 0.0:
            # Brakes hold the vehicle; this shuttle does not reverse in service.
            v_new = 0.0
            if s.accel_mps2 < 0.0:
                s.accel_mps2 = 0.0
        v_new = min(v_new, g.max_speed_mps * 1.05)
        v = 0.5 * (s.speed_mps + v_new)
        half_l = g.wheelbase_m / 2.0
        tan_f, tan_r = math.tan(s.steer_front_rad), math.tan(s.steer_rear_rad)
        beta = math.atan((tan_f + tan_r) / 2.0)
        yaw_rate = v * math.cos(beta) * (tan_f - tan_r) / g.wheelbase_m
        cx = s.x_m + half_l * math.cos(s.yaw_rad)
        cy = s.y_m + half_l * math.sin(s.yaw_rad)
        cx += v * math.cos(s.yaw_rad + beta) * dt_s
        cy += v * math.sin(s.yaw_rad + beta) * dt_s
        yaw = wrap_angle_rad(s.yaw_rad + yaw_rate * dt_s)
        s.x_m = cx - half_l * math.cos(yaw)
        s.y_m = cy - half_l * math.sin(yaw)
        s.yaw_rad = yaw
        s.yaw_rate_radps = yaw_rate
        s.speed_mps = v_new
