"""Shared closed-loop helper: a controller driving the simulator's bicycle along a path."""

from __future__ import annotations

import math

import numpy as np

from lastmile.control.coupled_mpc import SnowLionMpcController
from lastmile.control.lateral import LateralController
from lastmile.control.longitudinal import LongitudinalController
from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState

DT = 0.02


def drive_lateral(
    controller: LateralController,
    geometry: VehicleGeometry,
    path: Polyline,
    start: VehicleState,
    speed_mps: float,
    seconds: float,
) -> tuple[KinematicBicycle, np.ndarray]:
    """Drive at a held speed (the MPC's own acceleration for the MPC); returns the car and the
    wheelbase-centre cross-track errors (m) at every control step."""
    car = KinematicBicycle(geometry, ActuatorDynamics(), start)
    errors = []
    s_hint = None
    for _ in range(int(seconds / DT)):
        st = car.state
        pose = SE2(st.x_m, st.y_m, st.yaw_rad)
        if isinstance(controller, SnowLionMpcController):
            cmd = controller.step_coupled(DT, pose, st.speed_mps, path, speed_mps)
            accel, df, dr = cmd.accel_mps2, cmd.steer_front_rad, cmd.steer_rear_rad
        else:
            df, dr = controller.step(DT, pose, st.speed_mps, path)
            accel = 1.0 * (speed_mps - st.speed_mps)
        for _ in range(2):
            car.step(DT / 2, accel, df, dr, False)
        mid = SE2(car.state.x_m, car.state.y_m, car.state.yaw_rad).compose(
            SE2(geometry.wheelbase_m / 2, 0.0, 0.0)
        )
        f = path.project(mid.x_m, mid.y_m, hint_s_m=s_hint, window_m=10.0)
        s_hint = f.s_m
        errors.append(f.d_m)
    return car, np.asarray(errors)


def circle_path(radius_m: float, points: int = 720) -> Polyline:
    """A counter-clockwise circle about the origin, starting at (radius, 0)."""
    t = np.linspace(0.0, 2.0 * math.pi, points, endpoint=False)
    return Polyline(np.c_[radius_m * np.cos(t), radius_m * np.sin(t)], closed=True)


def start_on_circle(radius_m: float, geometry: VehicleGeometry, speed_mps: float) -> VehicleState:
    """Wheelbase centre on the circle at (radius, 0), heading +y."""
    half = geometry.wheelbase_m / 2.0
    return VehicleState(radius_m, -half, math.pi / 2, speed_mps=speed_mps)


def move_off_from_hold(
    controller: LongitudinalController, held_v_ref_mps: float, go_v_ref_mps: float
) -> tuple[float, float | None, np.ndarray]:
    """A longitudinal law on the bicycle model, held 2 s at a stop point where it stands, then told to
    go (no stop point, ``go_v_ref_mps``) for 5 s. Returns the last command of the hold, the time from
    the go to 0.05 m/s (None: never), and the actual acceleration averaged over 0.1 s windows (the
    10 Hz signal the comfort metrics read)."""
    car = KinematicBicycle(VehicleGeometry(), ActuatorDynamics(), VehicleState(0.0, 0.0, 0.0))
    held = 0.0
    for _ in range(int(2.0 / DT)):
        held = controller.step(DT, car.state.speed_mps, held_v_ref_mps, 0.0)
        car.step(DT, held, 0.0, 0.0, False)
    accels, moving_s = [], None
    for k in range(int(5.0 / DT)):
        a = controller.step(DT, car.state.speed_mps, go_v_ref_mps, None)
        car.step(DT, a, 0.0, 0.0, False)
        accels.append(car.state.accel_mps2)
        if moving_s is None and car.state.speed_mps > 0.05:
            moving_s = (k + 1) * DT
    per = round(0.1 / DT)
    return held, moving_s, np.asarray(accels[: len(accels) // per * per]).reshape(-1, per).mean(axis=1)
