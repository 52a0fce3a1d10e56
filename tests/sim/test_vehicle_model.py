import math

import pytest

from lastmile.core.errors import MessageError
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState


def _drive(all_wheel_steer: bool, steer: float, seconds: float = 20.0) -> KinematicBicycle:
    g = VehicleGeometry(all_wheel_steer=all_wheel_steer)
    car = KinematicBicycle(g, ActuatorDynamics(), VehicleState(0.0, 0.0, 0.0, speed_mps=3.0))
    for _ in range(int(seconds / 0.01)):
        car.step(0.01, 0.05, steer, -steer, False)
    return car


def test_steady_turn_radius_matches_the_kinematic_model_and_aws_halves_it():
    steer = 0.2
    r2ws = VehicleGeometry().wheelbase_m / math.tan(steer)
    front_only = _drive(False, steer)
    aws = _drive(True, steer)
    # Yaw rate = v / R: all-wheel steer with rear = -front doubles it for the same wheel angle.
    assert front_only.state.yaw_rate_radps == pytest.approx(front_only.state.speed_mps / r2ws, rel=0.02)
    assert aws.state.yaw_rate_radps == pytest.approx(2 * aws.state.speed_mps / r2ws, rel=0.02)


def test_acceleration_follows_the_command_with_lag_and_limits():
    g = VehicleGeometry()
    car = KinematicBicycle(g, ActuatorDynamics(accel_lag_s=0.25), VehicleState(0.0, 0.0, 0.0))
    for _ in range(25):
        car.step(0.01, 10.0, 0.0, 0.0, False)
    # One time constant: about 63 % of the (clamped) command.
    assert car.state.accel_mps2 == pytest.approx(0.63 * g.max_accel_mps2, rel=0.05)
    for _ in range(1000):
        car.step(0.01, 10.0, 0.0, 0.0, False)
    assert car.state.speed_mps <= g.max_speed_mps * 1.05 + 1e-9


def test_braking_stops_without_reversing():
    car = KinematicBicycle(VehicleGeometry(), ActuatorDynamics(), VehicleState(0.0, 0.0, 0.0, speed_mps=5.0))
    for _ in range(600):
        car.step(0.01, 0.0, 0.0, 0.0, True)
    assert car.state.speed_mps == 0.0
    x_stop = car.state.x_m
    for _ in range(100):
        car.step(0.01, -3.0, 0.0, 0.0, False)
    assert car.state.x_m == pytest.approx(x_stop)


def test_emergency_brake_stopping_distance_matches_v_squared_over_two_a():
    dyn = ActuatorDynamics(accel_lag_s=0.01)
    car = KinematicBicycle(VehicleGeometry(), dyn, VehicleState(0.0, 0.0, 0.0, speed_mps=5.0))
    while car.state.speed_mps > 0:
        car.step(0.01, 0.0, 0.0, 0.0, True)
    assert car.state.x_m == pytest.approx(5.0**2 / (2 * dyn.emergency_decel_mps2), rel=0.05)


def test_nan_command_is_rejected():
    car = KinematicBicycle(VehicleGeometry(), ActuatorDynamics(), VehicleState(0.0, 0.0, 0.0))
    with pytest.raises(MessageError, match="finite"):
        car.step(0.01, float("nan"), 0.0, 0.0, False)
