"""GEM's twist controller (its section II): target speed and yaw rate -> throttle, brake and steering.

Linear velocity (its Fig. 3): a proportional gain on the speed error gives an acceleration command,
limited for comfort; the IMU's acceleration is low-pass filtered (tau = 2 s); where acceleration is
wanted a PI loop on the acceleration error makes the throttle, itself filtered against jerk; where
deceleration is wanted an open-loop map makes the brake, b = 0.28 ln(a_cmd) + 0.90 clipped to [0, 1]
(a_cmd the deceleration's magnitude; GEM's braking is too nonlinear for a closed loop). Angular velocity:
the bicycle model turns the yaw rate into a wheel angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.control.command_filters import LowPassFilter
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.pedal_map import gem_brake_pedal
from lastmile.core.vehicle import VehicleGeometry

__all__ = [
    "GemTwistController",
    "PedalCommand",
    "TwistControllerConfig",
    "gem_brake_pedal",
    "steer_for_yaw_rate_rad",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class TwistControllerConfig:
    """GEM's published constants (IMU filter, brake map) and the gains it does not publish.

    The unpublished gains were chosen on ``sim.throttle_brake``'s plant (speed loop 1 /s, throttle PI
    0.4 and 0.4 /s: no limit cycle at 3 m/s behind the 2 s IMU filter, 3 % overshoot); a real vehicle
    needs its own.

    Attributes:
        speed_kp_per_s: speed error (m/s) -> acceleration command (m/s^2).
        max_accel_mps2, max_decel_mps2: comfort limits on the acceleration command (inside Snow Lion's
            measured -1.83 to 1.12 m/s^2).
        imu_lowpass_tau_s: GEM's IMU acceleration filter, tau = 2.
        throttle_kp, throttle_ki_per_s: PI from acceleration error (m/s^2) to throttle (0-1).
        throttle_lowpass_tau_s: the throttle output's filter.
        brake_log_gain, brake_offset: b = gain * ln(a_cmd) + offset (GEM: 0.28 and 0.90).
        hold_speed_mps, hold_brake: below this speed with a stop commanded, at least this brake
            (0.71 is the map's pedal for 0.5 m/s^2); a stop command never opens the throttle. The
            hold engages at standstill (0.01 m/s, as the cascaded PI's hold): engaged while still
            rolling, its 0.5 m/s^2 ends in a step when the wheels stop (at 0.3 m/s it gave +3.5
            m/s^3 at a bay, at 0.05 m/s +2.4, against the 2.5 and 1.84 m/s^3 comfort bounds). Above
            it the P-loop's -k_p v through the brake map, then the rolling resistance, bring the
            last centimetres to rest.
    """

    speed_kp_per_s: float = 1.0
    max_accel_mps2: float = 1.0
    max_decel_mps2: float = 1.5
    imu_lowpass_tau_s: float = 2.0
    throttle_kp: float = 0.4
    throttle_ki_per_s: float = 0.4
    throttle_lowpass_tau_s: float = 0.2
    brake_log_gain: float = 0.28
    brake_offset: float = 0.90
    hold_speed_mps: float = 0.01
    hold_brake: float = 0.71

    def __post_init__(self) -> None:
        for name in (
            "speed_kp_per_s",
            "max_accel_mps2",
            "max_decel_mps2",
            "throttle_ki_per_s",
            "brake_log_gain",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"TwistControllerConfig.{name}: expected a positive number, got {value}")


@dataclass(frozen=True, slots=True, kw_only=True)
class PedalCommand:
    """Throttle and brake pedal positions, each in [0, 1]; never both pressed.

    Attributes:
        throttle: 0 released, 1 full.
        brake: 0 released, 1 full.
        accel_cmd_mps2: the acceleration command they realise (for logs).
    """

    throttle: float
    brake: float
    accel_cmd_mps2: float


def steer_for_yaw_rate_rad(yaw_rate_radps: float, speed_mps: float, geometry: VehicleGeometry) -> float:
    """GEM's angular-velocity loop: the bicycle model's wheel angle for a yaw rate (all-wheel: half base)."""
    base = geometry.wheelbase_m / 2.0 if geometry.all_wheel_steer else geometry.wheelbase_m
    delta = math.atan(yaw_rate_radps * base / max(speed_mps, 0.5))
    return min(max(delta, -geometry.max_steer_rad), geometry.max_steer_rad)


class GemTwistController:
    """Speed P-loop -> acceleration command -> PI throttle or open-loop brake."""

    def __init__(self, config: TwistControllerConfig | None = None) -> None:
        self.config = c = config or TwistControllerConfig()
        self._imu = LowPassFilter(c.imu_lowpass_tau_s)
        self._throttle = LowPassFilter(c.throttle_lowpass_tau_s)
        self._integral = 0.0

    def reset(self) -> None:
        self._imu.reset()
        self._throttle.reset(0.0)
        self._integral = 0.0

    def step(
        self, dt_s: float, speed_mps: float, imu_accel_mps2: float, speed_cmd_mps: float
    ) -> PedalCommand:
        """Pedals from the measured speed, the IMU's longitudinal acceleration and the target speed."""
        if not (math.isfinite(speed_mps) and math.isfinite(imu_accel_mps2) and math.isfinite(speed_cmd_mps)):
            raise MessageError(
                f"GemTwistController.step: expected finite speed, acceleration and target, "
                f"got {speed_mps}, {imu_accel_mps2}, {speed_cmd_mps}"
            )
        c = self.config
        a_cmd = c.speed_kp_per_s * (speed_cmd_mps - speed_mps)
        a_cmd = min(max(a_cmd, -c.max_decel_mps2), c.max_accel_mps2)
        a_meas = self._imu.step(dt_s, imu_accel_mps2)
        brake = gem_brake_pedal(-a_cmd, c.brake_log_gain, c.brake_offset) if a_cmd < 0.0 else 0.0
        if speed_cmd_mps <= 0.0 and speed_mps < c.hold_speed_mps:
            # Stopping: the P-loop's command fades with the speed below the brake map's range, and the
            # throttle loop would creep on the filtered deceleration; hold the brake instead.
            brake = max(brake, c.hold_brake)
        if brake > 0.0 or speed_cmd_mps <= 0.0:
            # Deceleration the brake map can give: throttle off at once, brake open loop; the throttle
            # integrator restarts from zero next time. Smaller decelerations (the map's b = 0 below
            # exp(-0.90 / 0.28) = 0.04 m/s^2) stay with the throttle loop, which eases off instead:
            # switching there would reset the throttle on every small overshoot and cycle.
            self._integral = 0.0
            self._throttle.reset(0.0)
            return PedalCommand(throttle=0.0, brake=brake, accel_cmd_mps2=a_cmd)
        err = a_cmd - a_meas
        # Anti-windup: the integral alone never asks for more than full throttle or less than none.
        self._integral = min(max(self._integral + c.throttle_ki_per_s * err * dt_s, 0.0), 1.0)
        raw = min(max(c.throttle_kp * err + self._integral, 0.0), 1.0)
        throttle = self._throttle.step(dt_s, raw)
        return PedalCommand(throttle=throttle, brake=0.0, accel_cmd_mps2=a_cmd)
