"""The simulator's pedal plant: motor line, GEM brake curve, lags, and no rolling backwards."""

import math

import pytest

from lastmile.core.errors import MessageError
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.throttle_brake import ThrottleBrakeDynamics, ThrottleBrakeVehicle, brake_decel_mps2
from lastmile.sim.vehicle_model import VehicleState


def _car(speed: float = 0.0) -> ThrottleBrakeVehicle:
    return ThrottleBrakeVehicle(
        VehicleGeometry(), ThrottleBrakeDynamics(), VehicleState(0.0, 0.0, 0.0, speed_mps=speed)
    )


def test_full_throttle_from_rest_gives_the_rated_acceleration_after_the_lag():
    car = _car()
    for _ in range(300):
        car.step(0.01, 1.0, 0.0, 0.0, 0.0, False)
    g = VehicleGeometry()
    v = car.state.speed_mps
    expected = g.max_accel_mps2 * (1.0 - v / (1.2 * g.max_speed_mps)) - 0.05 - 6e-4 * v * v
    assert car.state.accel_mps2 == pytest.approx(expected, abs=0.02)
    assert 0.0 < v < 1.2 * g.max_speed_mps


def test_brake_follows_gems_curve_and_the_lag():
    car = _car(speed=5.0)
    car.step(0.01, 0.0, 0.9, 0.0, 0.0, False)
    first = -car.state.accel_mps2
    for _ in range(100):
        car.step(0.01, 0.0, 0.9, 0.0, 0.0, False)
    v = car.state.speed_mps
    assert -car.state.accel_mps2 == pytest.approx(1.0 + 0.05 + 6e-4 * v * v, abs=0.01)
    assert first < 0.2  # the brake builds up over its lag
    assert brake_decel_mps2(0.0) == 0.0
    assert brake_decel_mps2(1.0) == pytest.approx(math.exp(0.1 / 0.28))


def test_brakes_hold_at_rest_and_never_push_backwards():
    car = _car()
    for _ in range(100):
        car.step(0.01, 0.0, 1.0, 0.0, 0.0, False)
    assert car.state.speed_mps == 0.0 and car.state.x_m == 0.0


def test_non_finite_pedals_are_named():
    with pytest.raises(MessageError, match="finite pedals"):
        _car().step(0.01, math.nan, 0.0, 0.0, 0.0, False)
