"""aUToronto's cascaded speed controller (7.2.3, 7.2.5) over its trapezoidal velocity profile.

Outer PI: speed error -> desired acceleration, plus the profile's acceleration as feed-forward.
Inner loop: an integral on the acceleration error plus the feed-forward k_ff * a_des (aUToronto
multiplies the desired acceleration by an empirical constant to get torque; this drive-by-wire takes
an acceleration, so k_ff = 1). Braking follows aUToronto's method (2): where the loop's output and the
desired acceleration are both negative the desired deceleration is requested; where only the output is,
the output times k_neg. Safety stage (7.2.5): acceleration bounds, a jerk (rate) limit and a low-pass
filter on the command.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.control.command_filters import LowPassFilter, RateLimiter
from lastmile.control.velocity_profile import VelocityProfileConfig, trapezoidal_profile
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.vehicle_messages import Trajectory


@dataclass(frozen=True, slots=True, kw_only=True)
class CascadedPiConfig:
    """Gains and limits (aUToronto publishes the structure, not its gains).

    Attributes:
        profile: the trapezoidal velocity profile generator's limits.
        speed_kp_per_s, speed_ki_per_s2: outer PI, speed error (m/s) -> acceleration (m/s^2).
        speed_integral_limit_mps2: anti-windup bound of the outer integral's contribution.
        accel_ki_per_s: inner integral gain on the acceleration error.
        accel_integral_limit_mps2: bound of the inner integral's contribution.
        feedforward_gain: k_ff (1 for an acceleration-commanded drive-by-wire).
        negative_gain: k_neg of braking method (2).
        max_accel_mps2, max_decel_mps2: command bounds (Snow Lion's comfort envelope is -1.83 to 1.12).
        max_jerk_mps3: rate limit on the command (Snow Lion's measured jerk stays within 1.84 m/s^3).
        brake_jerk_factor: braking may ramp this many times faster than max_jerk_mps3 (1: the comfort
            limit holds both ways; the emergency brake is a separate command).
        command_lowpass_tau_s: low-pass filter on the command.
        accel_estimate_tau_s: low-pass on the differentiated speed when no IMU acceleration is given.
        stop_trigger_mps2: toward a stop point inside the path the reference starts slowing once
            reaching it needs this deceleration (WATonoBus's brake trigger).
        stop_margin_m: the ramp aims this far before the stop point (the loop's lag closes it).
        smooth_stop_speed_mps, smooth_stop_decel_per_s, smooth_stop_min_decel_mps2: below this speed,
            approaching rest, the deceleration is at most min_decel + per_s * speed.
        hold_decel_mps2: held once the profile asks for rest and the vehicle is stopped.
        hold_speed_mps: below this speed (with the profile at rest) the hold applies; low, so the
            last metres are closed by the speed loop gently rather than by the hold's step.
        preview_s: how far ahead (in time at the current speed) the feed-forward acceleration is read
            (the speed reference is read 0.1 s ahead): the drive's lag
            (0.25 s in the simulator) plus the time the jerk limit needs to take a_max to zero.
    """

    profile: VelocityProfileConfig = field(default_factory=VelocityProfileConfig)
    speed_kp_per_s: float = 1.0
    speed_ki_per_s2: float = 0.1
    speed_integral_limit_mps2: float = 0.3
    accel_ki_per_s: float = 0.5
    accel_integral_limit_mps2: float = 0.5
    feedforward_gain: float = 1.0
    negative_gain: float = 1.0
    max_accel_mps2: float = 1.1
    max_decel_mps2: float = 1.8
    max_jerk_mps3: float = 1.8
    brake_jerk_factor: float = 1.0
    command_lowpass_tau_s: float = 0.05
    accel_estimate_tau_s: float = 0.1
    stop_trigger_mps2: float = 0.6
    stop_margin_m: float = 0.2
    smooth_stop_speed_mps: float = 1.0
    smooth_stop_decel_per_s: float = 0.5
    smooth_stop_min_decel_mps2: float = 0.05
    hold_decel_mps2: float = 1.0
    hold_speed_mps: float = 0.01
    preview_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ("max_accel_mps2", "max_decel_mps2", "max_jerk_mps3", "speed_kp_per_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"CascadedPiConfig.{name}: expected a positive number, got {value}")


class CascadedPiSpeedController:
    """The longitudinal-controller interface: ``reference_speed_mps`` then ``step`` each control tick."""

    def __init__(self, config: CascadedPiConfig | None = None) -> None:
        self.config = c = config or CascadedPiConfig()
        self._speed_i = 0.0
        self._accel_i = 0.0
        self._ff_mps2 = 0.0
        self._last_speed: float | None = None
        self._gap_m: float | None = None
        self._accel_est = LowPassFilter(c.accel_estimate_tau_s)
        self._rate = RateLimiter(c.max_jerk_mps3, c.brake_jerk_factor * c.max_jerk_mps3)
        self._lowpass = LowPassFilter(c.command_lowpass_tau_s)
        self.accel_cmd_mps2 = 0.0
        self.v_des_mps = 0.0

    def reset(self, speed_mps: float) -> None:
        self._speed_i = self._accel_i = self._ff_mps2 = 0.0
        self._last_speed = speed_mps
        self._gap_m = None
        self._accel_est.reset(0.0)
        self._rate.reset(0.0)
        self._lowpass.reset(0.0)
        self.accel_cmd_mps2 = 0.0
        self.v_des_mps = speed_mps

    def reference_speed_mps(
        self, trajectory: Trajectory | None, path_s_m: float, speed_cap_mps: float
    ) -> float:
        """The profile's speed 0.1 s ahead of ``path_s_m``; its acceleration ``preview_s`` ahead is kept
        as the feed-forward of the next ``step``."""
        if trajectory is None:
            self._ff_mps2 = 0.0
            return speed_cap_mps
        pts = trajectory.points
        ahead = pts[:, 4] > path_s_m + 1e-6
        if not ahead.any():
            self._ff_mps2 = 0.0
            return 0.0 if self.config.profile.stop_at_end else speed_cap_mps
        # The profile starts where the vehicle is, at its current speed.
        s = np.concatenate([[path_s_m], pts[ahead, 4]])
        kappa = np.concatenate([[np.interp(path_s_m, pts[:, 4], pts[:, 3])], pts[ahead, 3]])
        # An estimated speed can dip a hair below zero at rest (filter noise); this shuttle never reverses.
        v0 = max(self._last_speed, 0.0) if self._last_speed is not None else 0.0
        # The decision's stop point (last step's gap: the stack asks for the reference first) truncates
        # the profile there, as a truncated reference route ends it at rest.
        stop_s = None if self._gap_m is None else path_s_m + max(self._gap_m - self.config.stop_margin_m, 0.0)
        pc = self.config.profile
        if stop_s is not None:
            # Toward a stop point the profile plans the gentler trigger deceleration, leaving the loop
            # the rest (up to max_decel_mps2) to absorb the drive's lag: planned at the profile's full
            # deceleration, the shuttle overshot a bay's stop point by a metre.
            pc = dataclasses.replace(pc, max_decel_mps2=min(pc.max_decel_mps2, self.config.stop_trigger_mps2))
        profile = trapezoidal_profile(s, kappa, speed_cap_mps, v0, pc, stop_s_m=stop_s)
        # Read the profile ahead by the loop's reaction (drive lag plus the jerk-limited ramp), so the
        # feed-forward eases off before the plateau rather than overshooting it.
        reach = max(v0, 0.5)
        self._ff_mps2 = profile.at(path_s_m + reach * self.config.preview_s)[1]
        return profile.at(path_s_m + reach * 0.1)[0]

    def step(
        self,
        dt_s: float,
        speed_mps: float,
        v_ref_mps: float,
        gap_to_stop_m: float | None,
        measured_accel_mps2: float | None = None,
    ) -> float:
        """Commanded acceleration (m/s^2); ``measured_accel_mps2`` is the IMU's, else the speed's rate."""
        if not (math.isfinite(speed_mps) and math.isfinite(v_ref_mps) and dt_s > 0.0):
            raise MessageError(
                f"CascadedPiSpeedController.step: expected finite speeds and dt > 0, "
                f"got {speed_mps}, {v_ref_mps}, {dt_s}"
            )
        c = self.config
        v_ref, ff = v_ref_mps, self._ff_mps2
        self._gap_m = gap_to_stop_m
        if gap_to_stop_m is not None:
            v_ref, ff = self._stop_ramp(dt_s, gap_to_stop_m, v_ref, ff)
        self.v_des_mps = v_ref
        a_meas = self._measured(dt_s, speed_mps, measured_accel_mps2)
        err = v_ref - speed_mps
        a_des = ff + c.speed_kp_per_s * err + self._speed_i
        a_des = min(max(a_des, -c.max_decel_mps2), c.max_accel_mps2)
        saturated = (a_des >= c.max_accel_mps2 and err > 0) or (a_des <= -c.max_decel_mps2 and err < 0)
        if not saturated:
            self._speed_i = _clamp(
                self._speed_i + c.speed_ki_per_s2 * err * dt_s, c.speed_integral_limit_mps2
            )
        self._accel_i = _clamp(
            self._accel_i + c.accel_ki_per_s * (a_des - a_meas) * dt_s, c.accel_integral_limit_mps2
        )
        out = c.feedforward_gain * a_des + self._accel_i
        if out < 0.0:
            out = a_des if a_des < 0.0 else c.negative_gain * out  # braking method (2)
        if v_ref <= 0.05 and speed_mps < c.hold_speed_mps:
            # At rest where the profile ends: hold the brake rather than creep on a small error.
            out = min(out, -c.hold_decel_mps2)
            self._speed_i = min(self._speed_i, 0.0)
        elif (
            v_ref < c.smooth_stop_speed_mps
            and speed_mps < c.smooth_stop_speed_mps
            and out < 0.0
            # Only with room for it (v / k bounds the distance the capped braking needs): short of room,
            # a stop point is not crept past for comfort (a crosswalk's, in the closed loop).
            and (
                gap_to_stop_m is None
                or gap_to_stop_m - c.stop_margin_m >= speed_mps / c.smooth_stop_decel_per_s
            )
        ):
            # Smooth stop: the last half metre per second is shed with a deceleration falling with the
            # speed, so the step to zero when the wheels stop is small (a full-rate stop there was a
            # 10 m/s^3 jerk at every stop in the closed loop).
            out = max(out, -(c.smooth_stop_min_decel_mps2 + c.smooth_stop_decel_per_s * speed_mps))
        out = min(max(out, -c.max_decel_mps2), c.max_accel_mps2)
        if speed_mps < c.hold_speed_mps and out > 0.0 and self.accel_cmd_mps2 < 0.0:
            # Moving off from the hold: a brake command on a standing vehicle accelerates nothing, so
            # it is released at once rather than ramped out at the jerk limit (as the WATonoBus law).
            self._rate.reset(0.0)
            self._lowpass.reset(0.0)
        self.accel_cmd_mps2 = self._lowpass.step(dt_s, self._rate.step(dt_s, out))
        return self.accel_cmd_mps2

    def _stop_ramp(self, dt_s: float, gap_m: float, v_ref: float, ff: float) -> tuple[float, float]:
        """A stop point inside the path ends the profile early. The reference slows as WATonoBus's
        eqs. (2)-(3) do, a_req = -v_des^2 / (2 gap), once that needs at least ``stop_trigger_mps2``:
        braking starts early and stays near-constant, and the reference integrates it (no step)."""
        c = self.config
        room = gap_m - c.stop_margin_m
        if room <= 0.05:
            return 0.0, 0.0
        a_req = self.v_des_mps**2 / (2.0 * room)
        if a_req < c.stop_trigger_mps2 and room >= 1.0:
            # Not braking yet, but never faster than the speed from which the trigger deceleration
            # still stops in time: the profile (which knows no stop point) must not accelerate into it.
            v_cap = math.sqrt(2.0 * c.stop_trigger_mps2 * room)
            return (v_cap, min(ff, 0.0)) if v_cap < v_ref else (v_ref, ff)
        v_stop = max(0.0, self.v_des_mps - a_req * dt_s)
        return (v_stop, -a_req) if v_stop < v_ref else (v_ref, ff)

    def _measured(self, dt_s: float, speed_mps: float, imu_mps2: float | None) -> float:
        last, self._last_speed = self._last_speed, speed_mps
        if imu_mps2 is not None:
            return self._accel_est.step(dt_s, imu_mps2)
        if last is None:
            return 0.0
        return self._accel_est.step(dt_s, (speed_mps - last) / dt_s)


def _clamp(x: float, limit: float) -> float:
    return min(max(x, -limit), limit)
