"""The raw-sensor adapter over a live world: sweep timing, pose history, frames the stack can read."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.rng import component_rng
from lastmile.core.sensor_frames import CameraDetections, LidarSweep
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.sim.agents import Agent
from lastmile.sim.raw_sensors import RawSensorRig
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState
from lastmile.sim.weather import Weather
from lastmile.sim.world import World

TICK_US = 10_000


def campus_world(weather: Weather) -> World:
    ego = KinematicBicycle(
        VehicleGeometry(), ActuatorDynamics(), VehicleState(250.0, -1.75, 0.0, speed_mps=4.0)
    )
    parked = Agent(
        id=5, cls=ObjectClass.CAR, x_m=275.0, y_m=-1.75, yaw_rad=0.0, speed_mps=0.0,
        length_m=4.5, width_m=1.8, rcs_dbsm=10.0,
    )  # fmt: skip
    return World(load_campus_map(), ego, [parked], weather, component_rng(0, "agents"))


def drive(rig: RawSensorRig, world: World, ticks: int) -> list[tuple[int, object, int]]:
    frames = []
    for tick in range(ticks):
        world.t_s = tick * TICK_US * 1e-6
        rig.world.ego.state.x_m = 250.0 + 4.0 * world.t_s  # 4 m/s straight along the lane
        frames += [(tick, f, lat) for f, lat in rig.sample(tick)]
    return frames


def test_rig_delivers_sweeps_each_period_and_camera_boxes_of_the_car_ahead() -> None:
    world = campus_world(Weather.CLEAR)
    rig = RawSensorRig(world, seed=0, tick_us=TICK_US, keep_truth=True)
    frames = drive(rig, world, 31)
    sweeps = [(t, f, lat) for t, f, lat in frames if isinstance(f, LidarSweep)]
    assert [(t, f.sensor_id) for t, f, _ in sweeps] == [
        (t, s) for t in (10, 20, 30) for s in ("front", "left", "right")
    ]
    for tick, sweep, latency in sweeps:
        assert int(sweep.stamp) == tick * TICK_US - 100_000  # stamped at the first column
        assert latency == 100_000 + 20_000
        assert len(sweep.points) > 1000
    front = [f for _, f, _ in sweeps if f.sensor_id == "front"][-1]
    # The parked car's rear face: 275 - 2.25 m, seen from the sensor as the shuttle drives at 4 m/s.
    ahead = front.points[(np.abs(front.points[:, 1]) < 0.5) & (front.points[:, 2] > -1.0)]
    sensor_x_start = 250.0 + 4.0 * 0.2 + rig.lidar_specs[0].x_m
    assert np.min(ahead[:, 0]) == pytest.approx(272.75 - sensor_x_start - 4.0 * 0.05, abs=0.3)
    truth = rig.lidar_truth["front"]
    assert len(truth.label) == len(front.points)
    assert set(truth.object_id[truth.object_id >= 0].tolist()) == {5}
    cams = [f for _, f, _ in frames if isinstance(f, CameraDetections) and f.camera_id == "front"]
    assert len(cams) == 4  # ticks 0, 10, 20, 30
    assert sum(len(c.boxes) for c in cams) >= 3
    assert all(c.boxes[0, 4] in (ObjectClass.CAR, ObjectClass.UNKNOWN) for c in cams if len(c.boxes))


def test_rig_refuses_a_lidar_period_off_the_tick() -> None:
    with pytest.raises(ConfigError, match="multiple"):
        RawSensorRig(campus_world(Weather.CLEAR), seed=0, tick_us=30_000)
