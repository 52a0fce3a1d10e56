"""Lateral control: WATonoBus's lookahead heading-error PID (all-wheel steer), pure pursuit, and the
registry of every lateral controller (Stanley, MPS, Snow Lion's MPC, GEM's waypoint follower)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

from lastmile.control.coupled_mpc import CoupledMpcConfig, SnowLionMpcController
from lastmile.control.path_errors import PlannedPointLaw
from lastmile.control.speed_reference import NoSpeedLaw, SteersFromPathAlone
from lastmile.control.stanley import (
    ModelPredictiveStanleyController,
    MpsConfig,
    StanleyConfig,
    StanleyController,
)
from lastmile.control.waypoint_follower import GemWaypointFollower, WaypointFollowerConfig
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry


@dataclass(frozen=True, slots=True, kw_only=True)
class LateralConfig:
    """Lookahead and gains.

    Attributes:
        lookahead_min_m, lookahead_time_s: lookahead distance = max(min, time * speed) (WATonoBus picks
            it by the vehicle's speed).
        kp, ki, kd: PID gains on the heading error to the lookahead point, scaled by
            wheelbase / lookahead so the loop gain stays constant as the lookahead grows.
        integral_limit_rad_s: anti-windup bound on the integral of the heading error.
        nus_lookahead_m: NUS's fixed pure-pursuit lookahead (its golf car runs at most 2 m/s).
        stanley, mps, mpc, waypoint: the parameters of the other registered controllers.
    """

    lookahead_min_m: float = 4.0
    lookahead_time_s: float = 1.0
    kp: float = 2.0
    ki: float = 0.05
    kd: float = 0.05
    integral_limit_rad_s: float = 0.5
    nus_lookahead_m: float = 3.0
    stanley: StanleyConfig = field(default_factory=StanleyConfig)
    mps: MpsConfig = field(default_factory=MpsConfig)
    mpc: CoupledMpcConfig = field(default_factory=CoupledMpcConfig)
    waypoint: WaypointFollowerConfig = field(default_factory=WaypointFollowerConfig)


class LateralController(Protocol):
    """Turns a path and the pose into wheel angles (front, rear)."""

    def step(
        self, dt_s: float, map_from_base: SE2, speed_mps: float, path: Polyline, rear_steer: bool = True
    ) -> tuple[float, float]: ...

    def set_speed_reference(self, speed_mps: float | None, accel_mps2: float = 0.0) -> None:
        """The longitudinal controller's speed (and its rate) for the next step; None holds the speed."""
        ...

    def speed_cap_mps(self, path: Polyline, path_s_m: float, cap_mps: float, decel_mps2: float) -> float:
        """The speed cap lowered by the controller's own speed law, if its source has one (GEM's
        v_max = sqrt(0.5 r)), reachable braking at ``decel_mps2``; otherwise ``cap_mps``."""
        ...

    def path_lead_m(self, rear_steer: bool = True) -> float:
        """How far ahead of the point the planner lays its path for (the rear axle; the centre of the
        wheelbase with all-wheel steer) the law measures its errors (m); the stack then feeds it that
        point's own path (``control.path_errors.path_ahead_of``)."""
        ...


def _reference_pose(map_from_base: SE2, geometry: VehicleGeometry, all_wheel: bool) -> SE2:
    """The point that follows the path: the rear axle with front steer, mid-wheelbase with all-wheel steer."""
    if not all_wheel:
        return map_from_base
    return map_from_base.compose(SE2(geometry.wheelbase_m / 2.0, 0.0, 0.0))


def _lookahead_point(path: Polyline, ref: SE2, lookahead_m: float) -> tuple[float, float]:
    f = path.project(ref.x_m, ref.y_m)
    x, y, _ = path.point_at(f.s_m + lookahead_m)
    return x, y


def _aim(
    map_from_base: SE2,
    speed_mps: float,
    path: Polyline,
    g: VehicleGeometry,
    c: LateralConfig,
    all_wheel: bool,
) -> tuple[float, float, float]:
    """Heading error to the lookahead point (rad), distance to it (m) and the lookahead distance (m)."""
    ref = _reference_pose(map_from_base, g, all_wheel)
    lookahead = max(c.lookahead_min_m, c.lookahead_time_s * speed_mps)
    lx, ly = _lookahead_point(path, ref, lookahead)
    error = wrap_angle_rad(math.atan2(ly - ref.y_m, lx - ref.x_m) - ref.yaw_rad)
    return error, max(math.hypot(lx - ref.x_m, ly - ref.y_m), 1e-3), lookahead


class LookaheadHeadingPid(SteersFromPathAlone, PlannedPointLaw, NoSpeedLaw):
    """WATonoBus: PID on the heading error to a lookahead point; rear = -delta with all-wheel steer."""

    def __init__(self, geometry: VehicleGeometry, config: LateralConfig | None = None) -> None:
        self.geometry = geometry
        self.config = config or LateralConfig()
        self._integral = 0.0
        self._last_error: float | None = None

    def step(
        self, dt_s: float, map_from_base: SE2, speed_mps: float, path: Polyline, rear_steer: bool = True
    ) -> tuple[float, float]:
        """``rear_steer=False`` keeps the rear wheels straight (at a curb, so the tail cannot swing in)."""
        g, c = self.geometry, self.config
        all_wheel = g.all_wheel_steer and rear_steer
        error, _, lookahead = _aim(map_from_base, speed_mps, path, g, c, all_wheel)
        if speed_mps > 0.1:
            self._integral = min(
                max(self._integral + error * dt_s, -c.integral_limit_rad_s), c.integral_limit_rad_s
            )
        derivative = 0.0 if self._last_error is None else (error - self._last_error) / dt_s
        self._last_error = error
        scale = g.wheelbase_m / lookahead
        if all_wheel:
            scale /= 2.0  # opposite rear steer doubles the yaw rate per wheel angle
        delta = scale * (c.kp * error + c.ki * self._integral + c.kd * derivative)
        delta = min(max(delta, -g.max_steer_rad), g.max_steer_rad)
        return delta, (-delta if all_wheel else 0.0)


class PurePursuitController(SteersFromPathAlone, PlannedPointLaw, NoSpeedLaw):
    """Pure pursuit (NUS golf car): the arc through the lookahead point, front steer or all-wheel steer."""

    def __init__(self, geometry: VehicleGeometry, config: LateralConfig | None = None) -> None:
        self.geometry = geometry
        self.config = config or LateralConfig()

    def step(
        self, dt_s: float, map_from_base: SE2, speed_mps: float, path: Polyline, rear_steer: bool = True
    ) -> tuple[float, float]:
        """``rear_steer=False`` keeps the rear wheels straight (at a curb, so the tail cannot swing in)."""
        g, c = self.geometry, self.config
        all_wheel = g.all_wheel_steer and rear_steer
        alpha, dist, _ = _aim(map_from_base, speed_mps, path, g, c, all_wheel)
        curvature = 2.0 * math.sin(alpha) / dist
        if all_wheel:
            delta = math.atan(curvature * g.wheelbase_m / 2.0)
        else:
            delta = math.atan(curvature * g.wheelbase_m)
        delta = min(max(delta, -g.max_steer_rad), g.max_steer_rad)
        return delta, (-delta if all_wheel else 0.0)


class LateralControllerName(StrEnum):
    """Registry names of the lateral controllers (the run configuration selects one)."""

    HEADING_PID = "heading_pid"  # WATonoBus, the default
    PURE_PURSUIT = "pure_pursuit"  # speed-scaled lookahead
    NUS_PURE_PURSUIT = "nus_pure_pursuit"  # NUS: fixed 3 m lookahead
    STANLEY = "stanley"  # aUToronto baseline
    MODEL_PREDICTIVE_STANLEY = "model_predictive_stanley"  # aUToronto MPS
    SNOW_LION_MPC = "snow_lion_mpc"  # Snow Lion coupled MPC (OSQP)
    GEM_WAYPOINT = "gem_waypoint"  # GEM waypoint follower


def _nus_pure_pursuit(geometry: VehicleGeometry, config: LateralConfig) -> PurePursuitController:
    fixed = dataclasses.replace(config, lookahead_min_m=config.nus_lookahead_m, lookahead_time_s=0.0)
    return PurePursuitController(geometry, fixed)


LATERAL_CONTROLLERS: dict[
    LateralControllerName, Callable[[VehicleGeometry, LateralConfig], LateralController]
] = {
    LateralControllerName.HEADING_PID: LookaheadHeadingPid,
    LateralControllerName.PURE_PURSUIT: PurePursuitController,
    LateralControllerName.NUS_PURE_PURSUIT: _nus_pure_pursuit,
    LateralControllerName.STANLEY: lambda g, c: StanleyController(g, c.stanley),
    LateralControllerName.MODEL_PREDICTIVE_STANLEY: lambda g, c: ModelPredictiveStanleyController(g, c.mps),
    LateralControllerName.SNOW_LION_MPC: lambda g, c: SnowLionMpcController(g, c.mpc),
    LateralControllerName.GEM_WAYPOINT: lambda g, c: GemWaypointFollower(g, c.waypoint),
}


def make_lateral_controller(
    name: LateralControllerName | str, geometry: VehicleGeometry, config: LateralConfig | None = None
) -> LateralController:
    """The lateral controller registered as ``name`` (a plain string is checked against the names)."""
    try:
        key = LateralControllerName(name)
    except ValueError:
        raise ConfigError(
            f"lateral controller: expected one of {[n.value for n in LateralControllerName]}, got {name!r}"
        ) from None
    return LATERAL_CONTROLLERS[key](geometry, config or LateralConfig())
