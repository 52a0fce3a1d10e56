"""The wired stack driving the vehicle model on the straight test road, from sensor frames only."""

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.sensor_frames import (
    DoorSensorFrame,
    DropOffRequestFrame,
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
from lastmile.runner.loop import ClosedLoop
from lastmile.safety.reliability_config import ReliabilityConfig, SensorSpec
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState
from lastmile.stack.shuttle_stack import ShuttleStack, StackConfig
from lastmile.stack.vehicle_build import build_safety
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


class _StraightRoadRig:
    """The loop's world for these tests: the vehicle model on the straight test road, ideal odometry,
    IMU, GNSS and door sensor, and a front radar that sees one obstacle at ``obstacle_x``."""

    def __init__(self, obstacle_x=None, call=None, door_open_after=None):
        self.car = KinematicBicycle(G, ActuatorDynamics(), VehicleState(20.0, 0.0, 0.0))
        self.obstacle_x, self.call, self.door_open_after = obstacle_x, call, door_open_after
        self.door_open = False
        self.states, self.door_cmds, self.onboard_y = [], [], []
        self._tick = 0

    def advance_world(self, tick):
        self._tick = tick

    def sensor_frames(self, tick):
        now, s = Stamp(tick * 10_000), self.car.state
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
            frames.append(DoorSensorFrame(stamp=now, door_open=self.door_open, person_in_doorway=False))
        if tick == 1 and self.call is not None:
            frames.append(StopCallFrame(stamp=now, stop_id=self.call, source="stop_button"))
        if tick % 5 == 0:
            objects = np.zeros((0, 6))
            if self.obstacle_x is not None:
                mount = SE2(s.x_m, s.y_m, s.yaw_rad).compose(FRONT)
                rel = mount.inverse().apply(self.obstacle_x, 0.0)
                if 0 < rel[0] < 60:
                    objects = np.array([[rel[0], rel[1], 0.0, 0.0, -15.0, 0.0]])
            # The radar reports every cycle, an empty list when it sees nothing.
            frames.append(RadarFrame(stamp=now, sensor_id="front", objects=objects))
        return frames

    def apply_command(self, cmd):
        s = self.car.state
        self.car.step(0.01, cmd.accel_mps2, cmd.steer_front_rad, cmd.steer_rear_rad, cmd.emergency_brake)
        self.door_cmds.append(cmd.door_open)
        if self.door_open_after is not None and cmd.door_open and s.speed_mps == 0.0:
            self.door_open = True
        elif not cmd.door_open:
            self.door_open = False

    def referee(self, takeover_request, reported_state=None):
        if reported_state is not None:
            self.states.append(reported_state)
            if reported_state == BehaviourState.ONBOARDING and self.car.state.speed_mps == 0.0:
                self.onboard_y.append((self.car.state.y_m, self.car.state.yaw_rad))

    def drain_events(self):
        return []


def _drive(layers, seconds, obstacle_x=None, call=None, door_open_after=None):
    config = StackConfig(radar_mounts={"front": FRONT}, reliability=ReliabilityConfig(sensors=RIG_SENSORS))
    stack = ShuttleStack(layers, G, config)
    rig = _StraightRoadRig(obstacle_x, call, door_open_after)
    ClosedLoop(rig, stack, build_safety(layers, config.reliability), 10_000).run(int(seconds * 100))
    return rig.car, rig.states, rig.door_cmds, stack, rig.onboard_y


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


class _DropOffRig(_StraightRoadRig):
    """The straight road rig whose passenger presses the seat's drop-off button at tick 1."""

    def sensor_frames(self, tick):
        frames = super().sensor_frames(tick)
        if tick == 1:
            frames.append(DropOffRequestFrame(stamp=Stamp(tick * 10_000), seat=0))
        return frames


def test_a_drop_off_button_makes_the_stack_stop_at_the_kerb_and_open_the_door(straight_layers):
    config = StackConfig(radar_mounts={"front": FRONT}, reliability=ReliabilityConfig(sensors=RIG_SENSORS))
    stack = ShuttleStack(straight_layers, G, config)
    rig = _DropOffRig(door_open_after=0.0)
    ClosedLoop(rig, stack, build_safety(straight_layers, config.reliability), 10_000).run(3000)
    assert BehaviourState.PULLOVER in rig.states and BehaviourState.ONBOARDING in rig.states
    assert any(rig.door_cmds) and stack.mission.drop_offs_served == 1
    y, yaw = rig.onboard_y[-1]
    # The plain kerb is the lane's edge (y = -1.75); no bay here. Kept at the curb-gap target.
    gap = (y - G.width_m / 2) - (-1.75)
    assert 0.05 < gap <= 0.3 and abs(yaw) < 0.02
    assert rig.car.state.x_m + G.front_from_rear_axle_m < 93.0, "stopped before the crosswalk's keep-out"


class _InterruptedPullOverRig(_StraightRoadRig):
    """The stop call's rig, with an emergency stop ordered once during the pull-over, when the front is
    ``short_m`` from the spot and braking for it (a snow phantom in the bay did this in the GNSS-outage
    scenario, raw, in snow)."""

    def __init__(self, short_m: float) -> None:
        super().__init__(call="S1", door_open_after=0.0)
        self.short_m = short_m
        self.stack: ShuttleStack | None = None
        self.interrupted_at_gap_m: float | None = None

    def referee(self, takeover_request, reported_state=None):
        super().referee(takeover_request, reported_state)
        stack, d = self.stack, self.stack._decision if self.stack is not None else None
        if stack is None or d is None or d.state != BehaviourState.PULLOVER or d.stop_at_s_m is None:
            return
        front_s = self.car.state.x_m + G.front_from_rear_axle_m
        gap = d.stop_at_s_m - front_s
        if self.interrupted_at_gap_m is None and gap < self.short_m and self.car.state.speed_mps > 0.3:
            self.interrupted_at_gap_m = gap
            stack.fsm.request_emergency(self._tick * 0.01, "test: interrupted pull-over")


@pytest.mark.parametrize("short_m", [0.9, 1.5])
def test_a_pull_over_an_emergency_stop_interrupts_short_of_its_spot_still_reaches_it(
    straight_layers, short_m
):
    """Released from the emergency stop, the longitudinal law starts afresh: at rest 1-2 m short of the
    spot it used to hold the brake for good (its rest hysteresis: a stop point it came to rest short of
    restarts only once it moved off by ``restart_gap_m``), and the shuttle stood 480 s in the bay; within
    the last metre (beyond the 0.6 m arrival) it braked at once and stood 350 s at the town's West Ave."""
    # Standing, the rig's noiseless GNSS repeats itself: not a frozen receiver here.
    sensors = tuple(
        SensorSpec(key="gnss", rate_hz=10.0, frozen_after=None) if s.key == "gnss" else s for s in RIG_SENSORS
    )
    config = StackConfig(radar_mounts={"front": FRONT}, reliability=ReliabilityConfig(sensors=sensors))
    stack = ShuttleStack(straight_layers, G, config)
    rig = _InterruptedPullOverRig(short_m=short_m)
    rig.stack = stack
    ClosedLoop(rig, stack, build_safety(straight_layers, config.reliability), 10_000).run(6000)
    assert rig.interrupted_at_gap_m is not None, "the pull-over was never interrupted"
    states = rig.states
    stopped = states.index(BehaviourState.EMERGENCY_STOP)
    assert BehaviourState.ONBOARDING in states[stopped:], "it never reached the spot after the stop"
    y, yaw = rig.onboard_y[-1]
    assert 0.0 < (y - G.width_m / 2) - (-4.75) <= 0.3 and abs(yaw) < 0.02
