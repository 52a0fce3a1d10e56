"""WATonoBus's longitudinal law (eqs. 1-3) with a curvature speed limit and a jerk-limited output, and the
registry of longitudinal controllers (with aUToronto's cascaded PI over its trapezoidal profile)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

import numpy as np

from lastmile.control.cascaded_pi import CascadedPiConfig, CascadedPiSpeedController
from lastmile.core.errors import ConfigError
from lastmile.core.vehicle_messages import Trajectory


@dataclass(frozen=True, slots=True, kw_only=True)
class LongitudinalConfig:
    """Parameters of the speed law.

    Attributes:
        nominal_accel_mps2: a_nom of eq. (1), toward the reference speed.
        brake_trigger_mps2: eq. (2) takes over once holding the gap needs at least this deceleration,
            so braking starts early and stays near-constant rather than late and hard.
        max_lateral_accel_mps2: comfort bound giving the curvature speed limit v = sqrt(a_lat / kappa).
        speed_gain_per_s: proportional gain from speed error to acceleration (the low-level loop).
        max_jerk_mps3: rate limit on the commanded acceleration (passenger comfort).
        cascaded_pi: parameters of aUToronto's cascaded PI controller (registry name ``cascaded_pi``).
    """

    nominal_accel_mps2: float = 0.8
    brake_trigger_mps2: float = 0.6
    max_decel_mps2: float = 3.0
    max_lateral_accel_mps2: float = 1.0
    speed_gain_per_s: float = 1.2
    max_jerk_mps3: float = 1.8
    cascaded_pi: CascadedPiConfig = field(default_factory=CascadedPiConfig)


class WatonobusLongitudinalController:
    """Desired speed V_des updated every control step, then tracked by a P loop.

    Eq. (1): V_des(k) = V_des(k-1) + a_nom * dt toward the reference speed.
    Eqs. (2)-(3): with an obstacle (or stop point) Delta s ahead, a_des = -V_des^2 / (2 (Delta s -
    Delta s_min)) and V_des(k) = V_des(k-1) + a_des * dt. The caller passes the stop point already
    shifted by Delta s_min, so here the gap is ``stop_s - front_s``.
    """

    def __init__(self, config: LongitudinalConfig | None = None) -> None:
        self.config = config or LongitudinalConfig()
        self.v_des_mps = 0.0
        self.accel_cmd_mps2 = 0.0

    def reset(self, speed_mps: float) -> None:
        self.v_des_mps = speed_mps
        self.accel_cmd_mps2 = 0.0

    def reference_speed_mps(
        self, trajectory: Trajectory | None, path_s_m: float, speed_cap_mps: float
    ) -> float:
        """The cap lowered wherever a curve ahead needs it, reachable with comfortable braking."""
        if trajectory is None:
            return speed_cap_mps
        pts = trajectory.points
        ahead = pts[:, 4] - path_s_m
        mask = (ahead >= 0.0) & (ahead <= 40.0)
        if not np.any(mask):
            return speed_cap_mps
        kappa = np.abs(pts[mask, 3])
        v_curve = np.sqrt(self.config.max_lateral_accel_mps2 / np.maximum(kappa, 1e-4))
        reachable = np.sqrt(v_curve**2 + 2.0 * self.config.nominal_accel_mps2 * ahead[mask])
        return float(min(speed_cap_mps, reachable.min()))

    def step(self, dt_s: float, speed_mps: float, v_ref_mps: float, gap_to_stop_m: float | None) -> float:
        """Commanded acceleration (m/s^2) for this step."""
        c = self.config
        a_free = min(max((v_ref_mps - self.v_des_mps) / dt_s, -c.nominal_accel_mps2), c.nominal_accel_mps2)
        a = a_free
        if gap_to_stop_m is not None:
            if gap_to_stop_m <= 0.05:
                a = -self.v_des_mps / dt_s
            else:
                a_des = -(self.v_des_mps**2) / (2.0 * gap_to_stop_m)
                if -a_des >= c.brake_trigger_mps2 or gap_to_stop_m < 1.0:
                    a = min(a_free, a_des)
        self.v_des_mps = max(0.0, self.v_des_mps + a * dt_s)
        target = a + c.speed_gain_per_s * (self.v_des_mps - speed_mps)
        if self.v_des_mps == 0.0 and speed_mps < 0.3:
            # Hold the vehicle firmly once stopped, rather than creeping on a tiny positive error.
            target = min(target, -1.0)
        target = min(max(target, -c.max_decel_mps2), 1.5)
        step = c.max_jerk_mps3 * dt_s
        # Braking harder may ramp twice as fast as easing off: safety first, comfort second.
        lo = self.accel_cmd_mps2 - 2.0 * step
        hi = self.accel_cmd_mps2 + step
        self.accel_cmd_mps2 = min(max(target, lo), hi)
        return self.accel_cmd_mps2


def stopping_gap_m(stop_front_s_m: float | None, front_s_m: float) -> float | None:
    """Gap from the front bumper to the decision's stop point (None when driving on)."""
    if stop_front_s_m is None or not math.isfinite(stop_front_s_m):
        return None
    return stop_front_s_m - front_s_m


class LongitudinalController(Protocol):
    """Turns the reference speed and the stop gap into an acceleration command (m/s^2)."""

    def reset(self, speed_mps: float) -> None: ...

    def reference_speed_mps(
        self, trajectory: Trajectory | None, path_s_m: float, speed_cap_mps: float
    ) -> float: ...

    def step(self, dt_s: float, speed_mps: float, v_ref_mps: float, gap_to_stop_m: float | None) -> float: ...


class LongitudinalControllerName(StrEnum):
    """Registry names of the longitudinal controllers (the run configuration selects one)."""

    WATONOBUS = "watonobus"  # eqs. (1)-(3), the default
    CASCADED_PI = "cascaded_pi"  # aUToronto: trapezoidal profile + cascaded PI with feed-forward


LONGITUDINAL_CONTROLLERS: dict[
    LongitudinalControllerName, Callable[[LongitudinalConfig], LongitudinalController]
] = {
    LongitudinalControllerName.WATONOBUS: WatonobusLongitudinalController,
    LongitudinalControllerName.CASCADED_PI: lambda c: CascadedPiSpeedController(c.cascaded_pi),
}


def make_longitudinal_controller(
    name: LongitudinalControllerName | str, config: LongitudinalConfig | None = None
) -> LongitudinalController:
    """The longitudinal controller registered as ``name`` (a plain string is checked against the names)."""
    try:
        key = LongitudinalControllerName(name)
    except ValueError:
        raise ConfigError(
            f"longitudinal controller: expected one of {[n.value for n in LongitudinalControllerName]}, "
            f"got {name!r}"
        ) from None
    return LONGITUDINAL_CONTROLLERS[key](config or LongitudinalConfig())
