"""aUToronto's lateral control (7.2.4): the Stanley law and Model Predictive Stanley (MPS).

Stanley (eq. 2): delta = psi + atan(k e / (k_s + v)) at the front axle, psi the heading error and e the
cross-track error. MPS (eq. 3): delta = sum_i K_i [psi + atan(k e / (k_s + v))]_i, the law applied along
a horizon over which the vehicle is propagated with a kinematic bicycle; the horizon shrinks with the
curvature ahead (gain scheduling, so the car does not cut corners) and the weights K_i fall with i.
Both commands pass aUToronto's safety stage (7.2.5): steering range, steering rate, low-pass filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.control.command_filters import SteeringOutput
from lastmile.control.path_errors import (
    PathTracker,
    check_speed,
    curvature_profile,
    path_errors,
    point_ahead,
)
from lastmile.control.speed_reference import NoSpeedLaw, SteersFromPathAlone
from lastmile.control.steer_lag import SHUTTLE_STEER_LAG_S, LagPredictor, SteeringLagModel
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry


@dataclass(frozen=True, slots=True, kw_only=True)
class StanleyConfig:
    """Gains of eq. (2) and the output stage.

    aUToronto does not publish its gains; k and k_s are those of the original Stanley controller
    (Hoffmann et al., 2007, the paper's ref. [20] line of work).

    Attributes:
        gain_per_s: k, how hard the cross-track error is closed (1/s).
        softening_mps: k_s, keeps the law finite at low speed.
        steer_lowpass_tau_s: time constant of the command's low-pass filter (7.2.5).
        actuator_lag_s: the steer-by-wire's first-order time constant (s) that plain Stanley compensates
            (``steer_lag.LagPredictor``: the law is evaluated at the pose predicted over this lag plus the
            low-pass filter's); 0 evaluates it at the present pose. None: the shuttle's drive-by-wire,
            ``steer_lag.SHUTTLE_STEER_LAG_S`` (0.15 s; None keeps the run's configuration echo as it was
            before the compensation existed). MPS has its own preview and ignores it.
    """

    gain_per_s: float = 2.5
    softening_mps: float = 1.0
    steer_lowpass_tau_s: float = 0.05
    actuator_lag_s: float | None = None

    @property
    def steer_lag_s(self) -> float:
        """The compensated lag (s): ``actuator_lag_s``, or the shuttle's when None."""
        return SHUTTLE_STEER_LAG_S if self.actuator_lag_s is None else self.actuator_lag_s

    def __post_init__(self) -> None:
        if not (self.gain_per_s > 0.0 and self.softening_mps > 0.0):
            raise ConfigError(
                f"StanleyConfig: expected gain_per_s > 0 and softening_mps > 0, "
                f"got {self.gain_per_s} and {self.softening_mps}"
            )
        if not (math.isfinite(self.steer_lag_s) and self.steer_lag_s >= 0.0):
            raise ConfigError(
                f"StanleyConfig.actuator_lag_s: expected a finite number >= 0 s, got {self.actuator_lag_s}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class MpsConfig:
    """Model Predictive Stanley: horizon, its schedule by curvature, and the weights.

    Attributes:
        stanley: the law applied at every horizon step.
        step_s: prediction step of the kinematic bicycle.
        horizon_max_steps, horizon_min_steps: horizon on straight road and in the tightest curve.
        curvature_straight_1pm, curvature_tight_1pm: curvature (ahead, over the longest horizon) at and
            below which the longest horizon is used, at and above which the shortest; linear between.
        weight_decay: K_i proportional to decay**i (normalised to sum 1): far steps weigh less.
    """

    stanley: StanleyConfig = field(default_factory=StanleyConfig)
    step_s: float = 0.1
    horizon_max_steps: int = 10
    horizon_min_steps: int = 2
    curvature_straight_1pm: float = 0.02
    curvature_tight_1pm: float = 0.15
    weight_decay: float = 0.7

    def __post_init__(self) -> None:
        if not (1 <= self.horizon_min_steps <= self.horizon_max_steps):
            raise ConfigError(
                f"MpsConfig: expected 1 <= horizon_min_steps <= horizon_max_steps, "
                f"got {self.horizon_min_steps} and {self.horizon_max_steps}"
            )
        if not (0.0 < self.curvature_straight_1pm < self.curvature_tight_1pm):
            raise ConfigError(
                f"MpsConfig: expected 0 < curvature_straight_1pm < curvature_tight_1pm, "
                f"got {self.curvature_straight_1pm} and {self.curvature_tight_1pm}"
            )
        if not (0.0 < self.weight_decay <= 1.0 and self.step_s > 0.0):
            raise ConfigError(
                f"MpsConfig: expected 0 < weight_decay <= 1 and step_s > 0, "
                f"got {self.weight_decay} and {self.step_s}"
            )


def stanley_law_rad(
    path: Polyline, front_axle: SE2, speed_mps: float, c: StanleyConfig, hint_s_m: float | None
) -> tuple[float, float]:
    """Eq. (2) at the front axle: (delta, station of the front axle on the path)."""
    e = path_errors(path, front_axle, hint_s_m)
    # psi: path heading minus yaw; e: positive when the axle is right of the path (steer left).
    psi = -e.heading_error_rad
    return psi + math.atan2(c.gain_per_s * -e.lateral_m, c.softening_mps + abs(speed_mps)), e.s_m


def bicycle_step(
    pose: SE2,
    speed_mps: float,
    steer_front_rad: float,
    steer_rear_rad: float,
    wheelbase_m: float,
    dt_s: float,
) -> SE2:
    """Kinematic bicycle (front and rear steer, rear-axle pose) advanced by ``dt_s``, as the simulator's."""
    half = wheelbase_m / 2.0
    tan_f, tan_r = math.tan(steer_front_rad), math.tan(steer_rear_rad)
    beta = math.atan((tan_f + tan_r) / 2.0)
    yaw_rate = speed_mps * math.cos(beta) * (tan_f - tan_r) / wheelbase_m
    cx = pose.x_m + half * math.cos(pose.yaw_rad) + speed_mps * math.cos(pose.yaw_rad + beta) * dt_s
    cy = pose.y_m + half * math.sin(pose.yaw_rad) + speed_mps * math.sin(pose.yaw_rad + beta) * dt_s
    yaw = wrap_angle_rad(pose.yaw_rad + yaw_rate * dt_s)
    return SE2(cx - half * math.cos(yaw), cy - half * math.sin(yaw), yaw)


class StanleyController(SteersFromPathAlone, NoSpeedLaw):
    """aUToronto's baseline: eq. (2) at the front axle; rear = -delta with all-wheel steer."""

    def __init__(self, geometry: VehicleGeometry, config: StanleyConfig | None = None) -> None:
        self.geometry = geometry
        self.config = config or StanleyConfig()
        self._output = SteeringOutput(
            geometry.max_steer_rad, geometry.max_steer_rate_radps, self.config.steer_lowpass_tau_s
        )
        self._front = PathTracker()
        c = self.config
        lag = SteeringLagModel(lag_s=c.steer_lag_s, max_rate_radps=geometry.max_steer_rate_radps)
        horizon = c.steer_lag_s + c.steer_lowpass_tau_s if c.steer_lag_s > 0.0 else 0.0
        self._lag = LagPredictor(lag, geometry.wheelbase_m, horizon)

    def path_lead_m(self, rear_steer: bool = True) -> float:
        """The front axle, where the law is measured, ahead of the planned point (the rear axle; the
        centre of the wheelbase with all-wheel steer): the stack feeds the front axle's own path."""
        g = self.geometry
        return g.wheelbase_m / 2.0 if g.all_wheel_steer and rear_steer else g.wheelbase_m

    def step(
        self, dt_s: float, map_from_base: SE2, speed_mps: float, path: Polyline, rear_steer: bool = True
    ) -> tuple[float, float]:
        """``rear_steer=False`` keeps the rear wheels straight (at a curb, so the tail cannot swing in).

        The law is evaluated at the pose the body will have when the wheels answer (``actuator_lag_s``).
        """
        check_speed("StanleyController.step", speed_mps)
        g = self.geometry
        all_wheel = g.all_wheel_steer and rear_steer
        self._lag.advance(dt_s)
        pose = self._lag.predict(map_from_base, speed_mps, all_wheel)
        front = point_ahead(pose, g.wheelbase_m)
        e = self._front.errors(path, front)
        psi = -e.heading_error_rad
        c = self.config
        raw = psi + math.atan2(c.gain_per_s * -e.lateral_m, c.softening_mps + abs(speed_mps))
        delta = self._output.step(dt_s, raw)
        self._lag.sent(delta)
        return delta, (-delta if all_wheel else 0.0)


class ModelPredictiveStanleyController(SteersFromPathAlone, NoSpeedLaw):
    """aUToronto's MPS (eq. 3) with the horizon scheduled by the curvature ahead."""

    def __init__(self, geometry: VehicleGeometry, config: MpsConfig | None = None) -> None:
        self.geometry = geometry
        self.config = config or MpsConfig()
        self._output = SteeringOutput(
            geometry.max_steer_rad, geometry.max_steer_rate_radps, self.config.stanley.steer_lowpass_tau_s
        )
        self._front = PathTracker()
        self.last_horizon_steps = self.config.horizon_max_steps

    def path_lead_m(self, rear_steer: bool = True) -> float:
        """The front axle, where the law is measured, ahead of the planned point (the rear axle; the
        centre of the wheelbase with all-wheel steer): the stack feeds the front axle's own path."""
        g = self.geometry
        return g.wheelbase_m / 2.0 if g.all_wheel_steer and rear_steer else g.wheelbase_m

    def horizon_steps(self, path: Polyline, s_front_m: float, speed_mps: float) -> int:
        """Steps in the horizon: the longest on straight road, shorter as the curvature ahead grows."""
        c = self.config
        reach = max(speed_mps, 1.0) * c.step_s * c.horizon_max_steps
        s = s_front_m + np.linspace(0.0, reach, 8)
        kappa = float(np.max(np.abs(curvature_profile(path, s))))
        t = (kappa - c.curvature_straight_1pm) / (c.curvature_tight_1pm - c.curvature_straight_1pm)
        t = min(max(t, 0.0), 1.0)
        return round(c.horizon_max_steps + t * (c.horizon_min_steps - c.horizon_max_steps))

    def step(
        self, dt_s: float, map_from_base: SE2, speed_mps: float, path: Polyline, rear_steer: bool = True
    ) -> tuple[float, float]:
        """``rear_steer=False`` keeps the rear wheels straight (at a curb, so the tail cannot swing in)."""
        check_speed("ModelPredictiveStanleyController.step", speed_mps)
        g, c = self.geometry, self.config
        all_wheel = g.all_wheel_steer and rear_steer
        e0 = self._front.errors(path, point_ahead(map_from_base, g.wheelbase_m))
        n = self.horizon_steps(path, e0.s_m, speed_mps)
        self.last_horizon_steps = n
        v = max(speed_mps, 0.5)  # propagate at walking pace at least, so the horizon sees ahead
        pose, hint = map_from_base, e0.s_m
        total, weight_sum, weight = 0.0, 0.0, 1.0
        for _ in range(n):
            front = point_ahead(pose, g.wheelbase_m)
            delta_i, hint = stanley_law_rad(path, front, speed_mps, c.stanley, hint)
            delta_i = min(max(delta_i, -g.max_steer_rad), g.max_steer_rad)
            total += weight * delta_i
            weight_sum += weight
            weight *= c.weight_decay
            pose = bicycle_step(pose, v, delta_i, -delta_i if all_wheel else 0.0, g.wheelbase_m, c.step_s)
        delta = self._output.step(dt_s, total / weight_sum)
        return delta, (-delta if all_wheel else 0.0)
