"""The wired stack driving the vehicle model on the straight test road, from sensor frames only."""

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.sensor_frames import (
    DoorSensorFrame,
    GnssInsFrame,
    ImuFrame,
    RadarFrame,
    StopCallFrame,
    WheelOdometryFrame,
)
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourState
from lastmile.decision.decision_config import DecisionConfig
from lastmile.safety.reliability_config import ReliabilityConfig, SensorSpec
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState
from lastmile.stack.shuttle_stack import ShuttleStack, StackConfig
from lastmile.tracking.prediction import PredictionConfig

G = VehicleGeometry()
FRONT = SE2(G.front_from_rear_axle_m, 0.0, 0.0)


# The sensors this rig feeds, which the stack's reliability monitor expects at their rates.
RIG_SENSORS = (
    SensorSpec(key="gnss", rate_hz=10.0),
    SensorSpec(key="imu", rate_hz=50.0, frozen_after=None),  # a noiseless test IMU repeats itself
    SensorSpec(key="odom", rate_hz=50.0, frozen_after=None),
    SensorSpec(key="door", rate_hz=10.0, frozen_after=None),
    SensorSpec(key="front", rate_hz=20.0, frozen_after=None),
)


def _drive(layers, seconds, obstacle_x=None, call=None, door_open_after=None):
    config = StackConfig(radar_mounts={"front": FRONT}, reliability=ReliabilityConfig(sensors=RIG_SENSORS))
    stack = ShuttleStack(layers, G, config)
    car = KinematicBicycle(G, ActuatorDynamics(), VehicleState(20.0, 0.0, 0.0))
    states, door_cmds, onboard_y = [], [], []
    door_open = False
    for tick in range(int(seconds * 100)):
        now = Stamp(tick * 10_000)
        s = car.state
        frames = []
        if tick % 2 == 0:
            frames.append(
                WheelOdometryFrame(stamp=now, speed_mps=s.speed_mps, steer_front_rad=0.0, steer_rear_rad=0.0)
            )
            frames.append(
                ImuFrame(stamp=now, yaw_rate_radps=s.yaw_rate_radps, accel_x_mps2=0.0, accel_y_mps2=0.0)
            )
        if tick % 10 == 0:
            frames.append(
                GnssInsFrame(
                    stamp=now,
                    x_m=s.x_m,
                    y_m=s.y_m,
                    yaw_rad=s.yaw_rad,
                    speed_mps=s.speed_mps,
                    pos_std_m=0.02,
                    yaw_std_rad=0.004,
                )
            )
            frames.append(DoorSensorFrame(stamp=now, door_open=door_open, person_in_doorway=False))
        if tick == 1 and call is not None:
            frames.append(StopCallFrame(stamp=now, stop_id=call, source="stop_button"))
        if tick % 5 == 0:
            objects = np.zeros((0, 6))
            if obstacle_x is not None:
                mount = SE2(s.x_m, s.y_m, s.yaw_rad).compose(FRONT)
                rel = mount.inverse().apply(obstacle_x, 0.0)
                if 0 < rel[0] < 60:
                    objects = np.array([[rel[0], rel[1], 0.0, 0.0, -15.0, 0.0]])
            # The radar reports every cycle, an empty list when it sees nothing.
            frames.append(RadarFrame(stamp=now, sensor_id="front", objects=objects))
        out = stack.tick(now, frames)
        cmd = out.command
        car.step(0.01, cmd.accel_mps2, cmd.steer_front_rad, cmd.steer_rear_rad, cmd.emergency_brake)
        if out.decision is not None:
            states.append(out.decision.state)
            if out.decision.state == BehaviourState.ONBOARDING and car.state.speed_mps == 0.0:
                onboard_y.append((car.state.y_m, car.state.yaw_rad))
        door_cmds.append(cmd.door_open)
        if door_open_after is not None and cmd.door_open and s.speed_mps == 0.0:
            door_open = True
        elif not cmd.door_open:
            door_open = False
    return car, states, door_cmds, stack, onboard_y


def test_the_stack_drives_off_and_cruises_near_20_kmh(straight_layers):
    car, states, _, stack, _ = _drive(straight_layers, 25.0)
    assert car.state.speed_mps > 0.95 * G.max_speed_mps
    assert abs(car.state.y_m) < 0.1
    assert set(states) == {BehaviourState.NORMAL_DRIVING}
    timing = stack.profiler.summary()
    assert {"control", "decision", "planning", "tracking", "estimation"} <= set(timing)


def test_the_stack_stops_before_a_goose_seen_only_by_radar(straight_layers):
    car, _, _, _, _ = _drive(straight_layers, 30.0, obstacle_x=90.0)
    front = car.state.x_m + G.front_from_rear_axle_m
    assert car.state.speed_mps == 0.0
    assert 90.0 - 0.25 - front > 1.0  # stopped short of it, with a gap
    assert 90.0 - front < 6.0


def test_a_stop_call_makes_the_stack_pull_over_into_the_bay_and_open_the_door(straight_layers):
    _, states, door_cmds, _, onboard_y = _drive(straight_layers, 60.0, call="S1", door_open_after=0.0)
    assert BehaviourState.PULLOVER in states and BehaviourState.ONBOARDING in states
    assert any(door_cmds)
    assert onboard_y
    y, yaw = onboard_y[-1]
    # Right side (centre line minus half the width, parallel to the curb) to the curb at y = -4.75.
    gap = (y - G.width_m / 2) - (-4.75)
    assert 0.0 < gap <= 0.3
    assert abs(yaw) < 0.02


def test_a_prediction_horizon_shorter_than_the_crosswalk_look_ahead_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"prediction.horizon_s: expected at least .*\(6.0 s\), got 4.0 s"):
        StackConfig(prediction=PredictionConfig(horizon_s=4.0))


def test_a_prediction_horizon_shorter_than_the_vehicle_look_ahead_is_refused() -> None:
    decision = DecisionConfig(vehicle_prediction_horizon_s=7.0)
    with pytest.raises(ConfigError, match=r"vehicle_prediction_horizon_s \(7.0 s\), got 6.0 s"):
        StackConfig(prediction=PredictionConfig(horizon_s=6.0), decision=decision)
