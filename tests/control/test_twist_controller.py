"""GEM's twist controller driving the simulator's throttle/brake model."""

import math

import numpy as np
import pytest

from lastmile.control.twist_controller import (
    GemTwistController,
    gem_brake_pedal,
    steer_for_yaw_rate_rad,
)
from lastmile.core.errors import MessageError
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.throttle_brake import ThrottleBrakeDynamics, ThrottleBrakeVehicle, brake_decel_mps2
from lastmile.sim.vehicle_model import VehicleState

DT = 0.02


def test_brake_map_is_gems_log_law_clipped():
    assert gem_brake_pedal(1.0) == pytest.approx(0.90)
    assert gem_brake_pedal(0.5) == pytest.approx(0.28 * math.log(0.5) + 0.90)
    assert gem_brake_pedal(3.0) == 1.0
    assert gem_brake_pedal(0.01) == 0.0
    assert gem_brake_pedal(0.0) == 0.0


def test_simulated_brake_inverts_the_map_in_its_range():
    for a in (0.1, 0.5, 1.0, 1.4):
        assert brake_decel_mps2(gem_brake_pedal(a)) == pytest.approx(a)


def _run(dyn: ThrottleBrakeDynamics, targets: list[tuple[float, float]]):
    g = VehicleGeometry()
    car = ThrottleBrakeVehicle(g, dyn, VehicleState(0.0, 0.0, 0.0))
    ctl = GemTwistController()
    speeds, accels, pedals = [], [], []
    for seconds, v_cmd in targets:
        for _ in range(int(seconds / DT)):
            st = car.state
            cmd = ctl.step(DT, st.speed_mps, st.accel_mps2, v_cmd)
            assert not (cmd.throttle > 0.0 and cmd.brake > 0.0)
            for _ in range(2):
                car.step(DT / 2, cmd.throttle, cmd.brake, 0.0, 0.0, False)
            speeds.append(car.state.speed_mps)
            accels.append(car.state.accel_mps2)
            pedals.append((cmd.throttle, cmd.brake))
    return car, np.asarray(speeds), np.asarray(accels), np.asarray(pedals)


def test_reaches_3_mps_on_throttle_then_stops_on_the_open_loop_brake():
    car, v, a, pedals = _run(ThrottleBrakeDynamics(), [(25.0, 3.0), (15.0, 0.0)])
    at_speed = v[int(20.0 / DT) : int(25.0 / DT)]
    assert np.abs(at_speed - 3.0).max() < 0.15
    assert pedals[: int(25.0 / DT), 0].max() > 0.1  # the throttle did the work
    assert pedals[int(25.0 / DT) :, 1].max() > 0.5  # the brake stopped it
    assert car.state.speed_mps == 0.0
    assert a.max() <= 1.12 and a.min() >= -1.83


def test_still_stops_with_brakes_30_percent_weaker_than_the_map_assumes():
    weak = ThrottleBrakeDynamics(brake_offset=0.90 + 0.28 * math.log(1 / 0.7))
    assert brake_decel_mps2(0.9, offset=weak.brake_offset) == pytest.approx(0.7)
    car, _, _, _ = _run(weak, [(25.0, 3.0), (20.0, 0.0)])
    nominal, _, _, _ = _run(ThrottleBrakeDynamics(), [(25.0, 3.0), (20.0, 0.0)])
    assert car.state.speed_mps == 0.0
    assert car.state.x_m > nominal.state.x_m + 0.2  # the weaker brake did take longer


def test_yaw_rate_to_wheel_angle_and_bad_input():
    g = VehicleGeometry(all_wheel_steer=False)
    assert steer_for_yaw_rate_rad(0.3, 3.0, g) == pytest.approx(math.atan(0.3 * g.wheelbase_m / 3.0))
    assert steer_for_yaw_rate_rad(10.0, 1.0, g) == g.max_steer_rad
    with pytest.raises(MessageError, match="finite"):
        GemTwistController().step(DT, math.nan, 0.0, 1.0)
