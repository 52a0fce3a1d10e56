"""Snow Lion's coupled MPC: its model, the cached OSQP workspace, its bounds and its tracking."""

import math

import numpy as np
import pytest
import scipy.linalg

from lastmile.control.coupled_mpc import CoupledMpcConfig, SnowLionMpcController, error_model, steady_state
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.vehicle_model import VehicleState

from .loop_helpers import circle_path, drive_lateral, start_on_circle

STRAIGHT = Polyline(np.array([[-10.0, 0.0], [400.0, 0.0]]))


def test_discretisation_is_the_exact_zero_order_hold_of_the_continuous_model():
    mpc = SnowLionMpcController(VehicleGeometry())
    v = 4.0
    ad, bd, ed, (a, b, c) = mpc.discretise(v, all_wheel=True)
    dt = mpc.config.step_s
    # Integrate the continuous lateral model finely under a held input and disturbance.
    x = np.array([0.3, -0.1, 0.05, 0.02])
    u, w = 0.1, 0.2
    xf = x.copy()
    for _ in range(20_000):
        xf = xf + (a @ xf + b * u + c * w) * (dt / 20_000)
    np.testing.assert_allclose(ad[:4, :4] @ x + bd[:4, 0] * u + ed[:4, 0] * w, xf, atol=1e-4)
    np.testing.assert_allclose(ad[4:, 4:], [[1.0, dt], [0.0, 1.0]])
    np.testing.assert_allclose(bd[4:, 1], [-dt * dt / 2, -dt])
    # Longitudinal and lateral parts are decoupled in A (only V_x couples them).
    assert np.all(ad[:4, 4:] == 0.0) and np.all(ad[4:, :4] == 0.0)
    assert np.allclose(scipy.linalg.expm(np.zeros((2, 2))), np.eye(2))


def test_counter_steer_with_equal_axles_is_a_pure_yaw_moment():
    c = CoupledMpcConfig()
    _, b, _ = error_model(c, 1.45, 1.45, 3.0, all_wheel=True)
    assert b[1] == 0.0 and b[3] > 0.0
    _, bf, _ = error_model(c, 1.45, 1.45, 3.0, all_wheel=False)
    assert bf[1] > 0.0


@pytest.mark.parametrize("all_wheel", [True, False])
def test_steady_state_holds_the_model_at_rest_in_a_curve(all_wheel):
    c = CoupledMpcConfig()
    a, b, cv = error_model(c, 1.45, 1.45, 3.0, all_wheel)
    psi_dot = np.array([3.0 / 15.0])
    e_psi, delta = steady_state(a, b, cv, psi_dot)
    x = np.array([0.0, 0.0, e_psi[0], 0.0])
    np.testing.assert_allclose(a @ x + b * delta[0] + cv * psi_dot[0], 0.0, atol=1e-9)
    kinematic = math.atan((1.45 if all_wheel else 2.9) / 15.0)
    assert delta[0] == pytest.approx(kinematic, abs=0.01)


def test_the_osqp_workspace_is_built_once_and_only_its_values_change():
    g = VehicleGeometry()
    mpc = SnowLionMpcController(g)
    mpc.step_coupled(0.02, SE2(0.0, 0.5, 0.0), 2.0, STRAIGHT, 3.0)
    solver = mpc._solver
    a0 = solver._derivative_cache["A"]
    indices, indptr, values = a0.indices.copy(), a0.indptr.copy(), a0.data.copy()
    mpc.step_coupled(0.02, SE2(0.1, 0.4, 0.01), 5.0, STRAIGHT, 5.0)
    assert mpc._solver is solver
    a1 = solver._derivative_cache["A"]
    np.testing.assert_array_equal(a1.indices, indices)
    np.testing.assert_array_equal(a1.indptr, indptr)
    assert not np.allclose(a1.data, values)  # another speed, another discretisation
    # The values written match a matrix assembled from scratch for that speed.
    ad, bd, _, _ = mpc.discretise(5.0, True)
    dense = a1.toarray()
    np.testing.assert_allclose(dense[6:12, 0:6], -ad)
    np.testing.assert_allclose(dense[0:6, 120:122], -bd)


def test_inputs_respect_the_steering_range_rate_and_acceleration_bounds():
    g = VehicleGeometry()
    mpc = SnowLionMpcController(g)
    last = 0.0
    for _ in range(20):
        cmd = mpc.step_coupled(0.02, SE2(0.0, -6.0, 0.0), 1.0, STRAIGHT, 5.6)
        assert cmd.solved
        assert abs(cmd.steer_front_rad) <= g.max_steer_rad + 1e-9
        assert abs(cmd.steer_front_rad - last) <= g.max_steer_rate_radps * mpc.config.step_s + 1e-3
        assert -g.comfort_decel_mps2 - 1e-6 <= cmd.accel_mps2 <= g.max_accel_mps2 + 1e-6
        last = cmd.steer_front_rad
    assert last > 0.3  # six metres right of the path: steering hard left by now


def test_speed_reference_drives_the_acceleration_both_ways():
    g = VehicleGeometry()
    up = SnowLionMpcController(g).step_coupled(0.02, SE2(0.0, 0.0, 0.0), 2.0, STRAIGHT, 4.0)
    down = SnowLionMpcController(g).step_coupled(0.02, SE2(0.0, 0.0, 0.0), 4.0, STRAIGHT, 2.0)
    hold = SnowLionMpcController(g).step_coupled(0.02, SE2(0.0, 0.0, 0.0), 3.0, STRAIGHT, 3.0)
    assert up.accel_mps2 > 0.3 and down.accel_mps2 < -0.3 and abs(hold.accel_mps2) < 0.05


def test_lateral_interface_tracks_the_held_speed_reference():
    g = VehicleGeometry()
    mpc = SnowLionMpcController(g)
    mpc.set_speed_reference(4.0)
    mpc.step(0.02, SE2(0.0, 0.0, 0.0), 2.0, STRAIGHT)
    assert mpc.last_command is not None and mpc.last_command.accel_mps2 > 0.3


@pytest.mark.parametrize("all_wheel", [True, False])
def test_circle_at_3_mps_tracked_within_3_cm_and_speed_held(all_wheel):
    g = VehicleGeometry(all_wheel_steer=all_wheel)
    r = 12.0
    mpc = SnowLionMpcController(g)
    car, err = drive_lateral(mpc, g, circle_path(r), start_on_circle(r, g, 2.0), 3.0, 15.0)
    assert np.abs(err[150:]).max() < 0.03
    assert car.state.speed_mps == pytest.approx(3.0, abs=0.1)
    assert mpc.solver_failures == 0


def test_bad_pose_and_bad_config_are_named():
    mpc = SnowLionMpcController(VehicleGeometry())
    with pytest.raises(MessageError, match="finite speed"):
        mpc.step(0.02, SE2(0.0, 0.0, 0.0), math.nan, STRAIGHT)
    with pytest.raises(ConfigError, match="speed reference"):
        mpc.step_coupled(0.02, SE2(0.0, 0.0, 0.0), 1.0, STRAIGHT, math.inf)
    with pytest.raises(ConfigError, match="horizon_steps"):
        CoupledMpcConfig(horizon_steps=1)
    with pytest.raises(ConfigError, match="cg_from_rear_axle_m"):
        SnowLionMpcController(VehicleGeometry(), CoupledMpcConfig(cg_from_rear_axle_m=5.0))


def test_same_inputs_give_bit_identical_commands():
    def run():
        g = VehicleGeometry()
        mpc = SnowLionMpcController(g)
        _, err = drive_lateral(mpc, g, STRAIGHT, VehicleState(0.0, 0.8, 0.0, speed_mps=2.0), 3.0, 3.0)
        return err

    np.testing.assert_array_equal(run(), run())
