"""LiDAR geometry: ranges, occlusion, per-point time and motion skew, determinism, bad configs."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.agents import Agent
from lastmile.sim.lidar import LidarSimulator
from lastmile.sim.lidar_rig import EgoTrack, LidarSpec, default_lidar_rig
from lastmile.sim.lidar_scene import (
    REFLECTIVITY,
    Cylinders,
    DynamicObjects,
    PointLabel,
    Segments,
    StaticLidarScene,
)
from lastmile.sim.lidar_weather import LidarWeather, lidar_weather

GEOM = VehicleGeometry()
RIG = default_lidar_rig(GEOM)
FRONT = RIG[0]


def flat_scene(
    walls: list[tuple[float, float, float, float, float, float, PointLabel, bool]],
) -> StaticLidarScene:
    """A flat world (ground plane at z = 0, no raster) with the given walls (x0, y0, x1, y1, z0, z1)."""
    a = np.array([w[:6] for w in walls], dtype=float).reshape(-1, 6)
    labels = np.array([int(w[6]) for w in walls], dtype=np.int8)
    segs = Segments(
        p0=a[:, 0:2],
        p1=a[:, 2:4],
        z_min_m=a[:, 4],
        z_max_m=a[:, 5],
        label=labels,
        reflectivity=np.array([REFLECTIVITY[PointLabel(lab)] for lab in labels]),
        retro=np.array([w[7] for w in walls], dtype=bool),
    )
    empty = DynamicObjects.empty().cylinders
    return StaticLidarScene(
        segments=segs,
        cylinders=Cylinders(**{f: getattr(empty, f) for f in Cylinders.__dataclass_fields__}),
        ground=None,
    )


def sim(scene: StaticLidarScene, weather: LidarWeather | None = None, seed: int = 0) -> LidarSimulator:
    return LidarSimulator(scene, RIG, weather or LidarWeather(), seed, GEOM)


STILL = EgoTrack.constant(0, 0.0, 0.0, 0.0)


def front_box(distance_m: float, height_m: float = 1.5, **kw: object) -> DynamicObjects:
    """A car whose rear face is ``distance_m`` ahead of the front LiDAR."""
    return DynamicObjects.empty().with_box(
        x_m=FRONT.x_m + distance_m + 2.25, y_m=0.0, yaw_rad=0.0, length_m=4.5, width_m=1.8, height_m=height_m,
        object_id=7, object_class=ObjectClass.CAR, **kw,  # type: ignore[arg-type]
    )  # fmt: skip


def test_box_ahead_is_hit_at_its_range() -> None:
    sweep, truth = sim(flat_scene([])).sweep_with_truth("front", Stamp(0), STILL, front_box(20.0), 100_000)
    on_car = truth.object_id == 7
    assert on_car.sum() > 50
    face = on_car & (truth.xyz_map_m[:, 2] < 1.49)  # below the roof line: the rear face
    roof = on_car & ~face
    x = sweep.points[face, 0]
    assert abs(float(np.median(x)) - 20.0) < 0.01
    assert np.all(np.abs(x - 20.0) < 0.1)  # the rear face is a plane at 20 m, noise sigma 2 cm
    # The sensor (1.9 m) looks down onto the 1.5 m roof: those returns lie on the roof plane.
    assert roof.sum() > 0
    assert np.all(np.abs(truth.xyz_map_m[roof, 2] - 1.5) < 1e-6)
    assert np.all((sweep.points[roof, 0] > 19.9) & (sweep.points[roof, 0] < 24.6))
    assert np.all(truth.object_class[on_car] == ObjectClass.CAR)


def test_pedestrian_behind_car_gets_no_points() -> None:
    def walker(objs: DynamicObjects) -> DynamicObjects:
        person = Agent(
            id=9, cls=ObjectClass.PEDESTRIAN, x_m=FRONT.x_m + 30.0, y_m=0.0, yaw_rad=0.0, speed_mps=0.0,
            length_m=0.5, width_m=0.5, rcs_dbsm=-5.0,
        )  # fmt: skip
        return DynamicObjects(boxes=objs.boxes, cylinders=DynamicObjects.from_agents([person]).cylinders)

    alone = sim(flat_scene([])).sweep_with_truth(
        "front", Stamp(0), STILL, walker(DynamicObjects.empty()), 100_000
    )[1]
    assert (alone.object_id == 9).sum() > 20  # seen when nothing stands in front
    # A van taller than the sensor (1.9 m): a car would let the beams over its roof reach the head.
    van = front_box(10.0, height_m=2.4)
    hidden = sim(flat_scene([])).sweep_with_truth("front", Stamp(0), STILL, walker(van), 100_000)[1]
    assert (hidden.object_id == 9).sum() == 0
    assert (hidden.object_id == 7).sum() > 100


def test_timestamps_follow_azimuth_and_the_body_is_cropped() -> None:
    sweep = sim(flat_scene([])).sweep("front", Stamp(0), STILL, DynamicObjects.empty(), 0)
    t = sweep.points[:, 5]
    assert np.all(np.diff(t) >= 0) and t.min() >= 0 and t.max() < FRONT.period_us
    az = np.unwrap(np.arctan2(sweep.points[:, 1], sweep.points[:, 0]).astype(float))
    # Clockwise spin: azimuth falls as time rises, about 2 pi per period.
    slope = np.polyfit(t, az, 1)[0] * FRONT.period_us
    assert slope == pytest.approx(-2 * math.pi, rel=0.02)
    # The front unit's rear half looks into the shuttle's body: nothing comes back from there.
    behind = np.abs(np.arctan2(sweep.points[:, 1], sweep.points[:, 0])) > math.radians(120.0)
    assert behind.sum() == 0
    bx = sweep.points[:, 0] + FRONT.x_m
    inside = (
        (bx > -GEOM.rear_overhang_m) & (bx < GEOM.front_from_rear_axle_m) & (np.abs(sweep.points[:, 1]) < 1.0)
    )
    assert inside.sum() == 0


def test_ego_motion_skews_a_wall_by_speed_times_time() -> None:
    wall = flat_scene([(40.0, -30.0, 40.0, 30.0, 0.0, 5.0, PointLabel.BUILDING, False)])
    speed = 5.0
    moving = EgoTrack.constant(0, 0.0, 0.0, 0.0, speed_mps=speed)
    for track, expected in ((STILL, 0.0), (moving, -speed)):
        sweep, truth = sim(wall).sweep_with_truth("front", Stamp(0), track, DynamicObjects.empty(), 0)
        on = truth.label == PointLabel.BUILDING
        t_s = sweep.points[on, 5].astype(float) * 1e-6
        slope = np.polyfit(t_s, sweep.points[on, 0].astype(float), 1)[0]
        assert slope == pytest.approx(expected, abs=0.15)


def test_moving_car_is_drawn_where_it_is_when_the_beam_passes() -> None:
    car = front_box(15.0, vx_mps=0.0, vy_mps=4.0)
    sweep, truth = sim(flat_scene([])).sweep_with_truth("front", Stamp(0), STILL, car, 50_000)
    on = truth.object_id == 7
    # The car crosses ahead; its points' map y must match its centre track within its half width.
    t_s = sweep.points[on, 5] * 1e-6
    centre_y = 4.0 * (t_s - 0.05)
    assert np.all(np.abs(truth.xyz_map_m[on, 1] - centre_y) <= 0.9 + 1e-6)


def test_goose_at_30_m_gets_enough_points() -> None:
    goose = DynamicObjects.empty().with_box(
        x_m=FRONT.x_m + 30.0, y_m=0.0, yaw_rad=math.pi / 2, length_m=0.5, width_m=0.3, height_m=0.4,
        object_id=3, object_class=ObjectClass.ANIMAL,
    )  # fmt: skip
    truth = sim(flat_scene([])).sweep_with_truth("front", Stamp(0), STILL, goose, 0)[1]
    assert (truth.object_id == 3).sum() >= 6


def test_same_seed_same_sweep_bit_for_bit() -> None:
    scene = flat_scene([(25.0, -30.0, 25.0, 30.0, 0.0, 5.0, PointLabel.BUILDING, False)])
    snow = replace(lidar_weather("snow"), snow_bank_width_m=0.0)  # flakes only: the flat world has no curbs
    runs = [
        sim(scene, snow, seed)
        .sweep("front", Stamp(0), EgoTrack.constant(0, 0, 0, 0, 3.0), front_box(8.0), 0)
        .points
        for seed in (4, 4, 5)
    ]
    assert runs[0].tobytes() == runs[1].tobytes()
    assert runs[0].tobytes() != runs[2].tobytes()


@settings(max_examples=25, deadline=None)
@given(distance=st.floats(3.0, 60.0), yaw=st.floats(-math.pi, math.pi))
def test_wall_points_lie_on_the_wall_for_any_pose(distance: float, yaw: float) -> None:
    """Whatever the shuttle's heading, returns from a wall lie on it (to noise) and none lie behind it."""
    c, s = math.cos(yaw), math.sin(yaw)
    sx, sy = FRONT.x_m * c, FRONT.x_m * s  # the front sensor in the map
    cx, cy = sx + distance * c, sy + distance * s  # a wall across the heading, ``distance`` ahead
    wall = flat_scene(
        [(cx + 20 * s, cy - 20 * c, cx - 20 * s, cy + 20 * c, 0.0, 4.0, PointLabel.BUILDING, False)]
    )
    sweep, truth = sim(wall).sweep_with_truth(
        "front", Stamp(0), EgoTrack.constant(0, 0.0, 0.0, yaw), DynamicObjects.empty(), 0
    )
    on = truth.label == PointLabel.BUILDING
    assert on.sum() > 0
    assert np.all(np.abs(sweep.points[on, 0] - distance) < 0.12)
    ahead = np.abs(sweep.points[:, 1]) < 10.0  # the wall spans 20 m either side: rays pass its ends
    assert np.all(sweep.points[ahead, 0] < distance + 0.12)


def test_bad_configs_raise_clear_errors() -> None:
    with pytest.raises(ConfigError, match="x_m"):
        LidarSpec(sensor_id="f", x_m=float("nan"), y_m=0.0, z_m=1.0, yaw_rad=0.0, elevations_deg=(0.0,))
    with pytest.raises(ConfigError, match="azimuth_res_deg"):
        LidarSpec(
            sensor_id="f", x_m=0.0, y_m=0.0, z_m=1.0, yaw_rad=0.0, elevations_deg=(0.0,), azimuth_res_deg=-0.2
        )
    with pytest.raises(ConfigError, match="echoes_per_kray"):
        LidarWeather(echoes_per_kray=-1.0)
    with pytest.raises(ConfigError, match="expected one of"):
        lidar_weather("hail")
    with pytest.raises(ConfigError, match="intensity"):
        lidar_weather("snow", intensity=5.0)
    with pytest.raises(MessageError, match="finite"):
        EgoTrack(t_us=np.array([0, 1]), x_m=np.array([0.0, np.nan]), y_m=np.zeros(2), yaw_rad=np.zeros(2))
    with pytest.raises(ConfigError, match="sensor id"):
        sim(flat_scene([])).sweep("roof", Stamp(0), STILL, DynamicObjects.empty(), 0)
