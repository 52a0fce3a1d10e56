"""Every registered lateral controller: built by name, converges onto a straight path and holds a curve."""

import math

import numpy as np
import pytest

from lastmile.control.lateral import LATERAL_CONTROLLERS, LateralControllerName, make_lateral_controller
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.vehicle_model import VehicleState

from .loop_helpers import circle_path, drive_lateral, start_on_circle


def test_every_name_is_registered_and_plain_strings_are_accepted():
    assert set(LATERAL_CONTROLLERS) == set(LateralControllerName)
    for name in LateralControllerName:
        a = make_lateral_controller(name, VehicleGeometry())
        b = make_lateral_controller(name.value, VehicleGeometry())
        assert type(a) is type(b)


def test_unknown_name_lists_every_registered_name():
    with pytest.raises(ConfigError) as err:
        make_lateral_controller("lqr", VehicleGeometry())
    for name in LateralControllerName:
        assert name.value in str(err.value)


@pytest.mark.parametrize("name", list(LateralControllerName))
@pytest.mark.parametrize("all_wheel", [True, False])
def test_converges_from_a_one_metre_offset_onto_a_straight_path(name, all_wheel):
    g = VehicleGeometry(all_wheel_steer=all_wheel)
    path = Polyline(np.array([[-10.0, 0.0], [400.0, 0.0]]))
    lat = make_lateral_controller(name, g)
    car, err = drive_lateral(lat, g, path, VehicleState(0.0, 1.0, 0.0, speed_mps=3.0), 3.0, 20.0)
    assert abs(err[-1]) < 0.05, f"{name}: final cross-track {err[-1]:.3f} m"
    assert abs(car.state.yaw_rad) < 0.02
    # It actually moved toward the path rather than starting there.
    assert abs(err[0]) > 0.5


@pytest.mark.parametrize("name", list(LateralControllerName))
def test_holds_a_15_m_circle_at_3_mps_within_10_cm(name):
    g = VehicleGeometry()
    r = 15.0
    lat = make_lateral_controller(name, g)
    _, err = drive_lateral(lat, g, circle_path(r), start_on_circle(r, g, 3.0), 3.0, 20.0)
    assert np.abs(err[100:]).max() < 0.10, f"{name}: peak {np.abs(err[100:]).max():.3f} m"


def test_rear_wheels_stay_straight_when_rear_steer_is_off():
    g = VehicleGeometry(all_wheel_steer=True)
    path = Polyline(np.array([[-10.0, 0.0], [400.0, 0.0]]))
    for name in LateralControllerName:
        lat = make_lateral_controller(name, g)
        front, rear = lat.step(0.02, SE2(0.0, 1.0, 0.0), 3.0, path, rear_steer=False)
        assert rear == 0.0, name
        assert front < 0.0, f"{name}: a car left of the path steers right, got {front}"
        assert math.isfinite(front)
