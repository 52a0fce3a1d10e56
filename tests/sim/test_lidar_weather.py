"""LiDAR on the campus map: curb step, snow bank and lane cover, precipitation echoes, fog, intensity."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.sim.lidar import LidarSimulator, LidarTruth
from lastmile.sim.lidar_rig import EgoTrack, LidarSpec, default_lidar_rig
from lastmile.sim.lidar_scene import DynamicObjects, PointLabel, StaticLidarScene, static_scene
from lastmile.sim.lidar_weather import LidarWeather, lidar_weather
from tests.sim.test_lidar_geometry import flat_scene

GEOM = VehicleGeometry()
RIG = default_lidar_rig(GEOM)
CURB_Y = -3.5  # the outer (right) curb of the ring's bottom straight; the shuttle's lane centre is -1.75


@pytest.fixture(scope="module")
def campus() -> StaticLidarScene:
    return static_scene(load_campus_map())


def rig_in_map(
    scene: StaticLidarScene, weather: LidarWeather, x_m: float = 250.0, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, LidarTruth]:
    """All three sensors' points in the map frame (shuttle standing in its lane), ranges and truth."""
    sim = LidarSimulator(scene, RIG, weather, seed, GEOM)
    ego = EgoTrack.constant(0, x_m, -1.75, 0.0)
    pts, ranges, truths = [], [], []
    for spec in RIG:
        sweep, truth = sim.sweep_with_truth(spec.sensor_id, Stamp(0), ego, DynamicObjects.empty(), 0)
        pts.append(sensor_to_map(sweep.points, spec, x_m, -1.75))
        ranges.append(np.linalg.norm(sweep.points[:, :3], axis=1))
        truths.append(truth)
    truth = LidarTruth(
        label=np.concatenate([t.label for t in truths]),
        object_id=np.concatenate([t.object_id for t in truths]),
        object_class=np.concatenate([t.object_class for t in truths]),
        xyz_map_m=np.concatenate([t.xyz_map_m for t in truths]),
    )
    return np.concatenate(pts), np.concatenate(ranges), truth


def sensor_to_map(points: np.ndarray, spec: LidarSpec, x_m: float, y_m: float) -> np.ndarray:
    c, s = math.cos(spec.yaw_rad), math.sin(spec.yaw_rad)
    px, py = points[:, 0].astype(float), points[:, 1].astype(float)
    return np.column_stack(
        [x_m + spec.x_m + c * px - s * py, y_m + spec.y_m + s * px + c * py, points[:, 2] + spec.z_m]
    )


def band_z(pts: np.ndarray, d0: float, d1: float) -> float:
    """Median height of points whose distance inside the curb (towards the lane) is in [d0, d1]."""
    d = pts[:, 1] - CURB_Y
    sel = (d >= d0) & (d <= d1) & (pts[:, 0] > 230.0) & (pts[:, 0] < 270.0) & (pts[:, 2] < 0.5)
    assert sel.sum() > 20, f"too few points in band [{d0}, {d1}]: {sel.sum()}"
    return float(np.median(pts[sel, 2]))


def test_curb_step_is_visible_in_clear_weather(campus: StaticLidarScene) -> None:
    pts, _, truth = rig_in_map(campus, lidar_weather("clear"))
    assert (truth.label == PointLabel.CURB).sum() > 10
    assert band_z(pts, 0.1, 0.5) == pytest.approx(0.0, abs=0.03)  # road
    assert band_z(pts, -0.5, -0.1) == pytest.approx(0.15, abs=0.03)  # sidewalk


def test_snow_bank_hides_the_curb_step(campus: StaticLidarScene) -> None:
    pts, _, truth = rig_in_map(campus, lidar_weather("snow"))
    assert (truth.label == PointLabel.CURB).sum() == 0
    assert (truth.label == PointLabel.SNOW).sum() > 10
    inside, outside = band_z(pts, 0.0, 0.15), band_z(pts, -0.3, -0.05)
    assert abs(outside - inside) < 0.05  # no step at the curb line
    assert band_z(pts, 0.15, 0.45) > 0.04  # the bank slopes down into the lane
    assert band_z(pts, 1.0, 1.5) == pytest.approx(0.0, abs=0.05)  # the lane beyond is bare


def test_snow_can_cover_part_of_the_lane(campus: StaticLidarScene) -> None:
    weather = lidar_weather("snow", snow_cover_lane_m=1.0)
    pts, _, _ = rig_in_map(campus, weather)
    assert band_z(pts, 0.3, 0.9) == pytest.approx(0.15, abs=0.04)
    bare = weather.bare_road_from_curb_m
    assert bare == pytest.approx(1.6)
    assert band_z(pts, bare + 0.05, bare + 0.6) == pytest.approx(0.0, abs=0.02)  # the road is bare again


def test_snowflakes_add_near_range_points(campus: StaticLidarScene) -> None:
    def near_free_space(weather: LidarWeather) -> int:
        pts, ranges, truth = rig_in_map(campus, weather)
        return int(((ranges < 5.0) & (pts[:, 2] > 0.3) & (truth.label != PointLabel.EGO)).sum())

    clear, snow = near_free_space(lidar_weather("clear")), near_free_space(lidar_weather("snow"))
    heavy = near_free_space(lidar_weather("snow", intensity=2.0))
    assert clear == 0
    assert snow > 100
    assert heavy > 1.5 * snow


def test_fog_shortens_the_range(campus: StaticLidarScene) -> None:
    def reach(weather: LidarWeather) -> float:
        _, ranges, truth = rig_in_map(campus, weather)
        return float(ranges[truth.label != PointLabel.WEATHER_NOISE].max())

    clear, fog = reach(lidar_weather("clear")), reach(lidar_weather("fog"))
    assert clear > 80.0
    assert fog < 60.0


def test_wet_road_in_rain_returns_dimmer(campus: StaticLidarScene) -> None:
    def road_intensity(weather: LidarWeather) -> float:
        sim = LidarSimulator(campus, RIG, weather, 0, GEOM)
        sweep, truth = sim.sweep_with_truth(
            "front", Stamp(0), EgoTrack.constant(0, 250.0, -1.75, 0.0), DynamicObjects.empty(), 0
        )
        return float(np.median(sweep.points[truth.label == PointLabel.ROAD, 3]))

    assert road_intensity(lidar_weather("rain")) < 0.7 * road_intensity(lidar_weather("clear"))


def test_retro_reflective_sign_returns_high_intensity() -> None:
    scene = flat_scene(
        [
            (20.0, -0.3, 20.0, 0.3, 1.7, 2.3, PointLabel.SIGN, True),
            (20.0, 2.0, 20.0, 8.0, 0.0, 6.0, PointLabel.BUILDING, False),
        ]
    )
    sim = LidarSimulator(scene, RIG, lidar_weather("clear"), 0, GEOM)
    sweep, truth = sim.sweep_with_truth(
        "front", Stamp(0), EgoTrack.constant(0, 0, 0, 0), DynamicObjects.empty(), 0
    )
    intensity = sweep.points[:, 3]
    assert np.median(intensity[truth.label == PointLabel.SIGN]) > 200
    assert np.median(intensity[truth.label == PointLabel.BUILDING]) < 120
    assert np.median(intensity[truth.label == PointLabel.ROAD]) < 40  # asphalt is dark


def test_snow_bank_wider_than_the_stored_band_is_refused() -> None:
    from lastmile.core.errors import ConfigError

    with pytest.raises(ConfigError, match="snow_bank_width_m"):
        replace(lidar_weather("snow"), snow_bank_width_m=5.0)


def test_a_sweep_with_no_returns_still_gets_its_precipitation_echoes() -> None:
    # Fog so dense that no surface return comes back (a unit in a whiteout): the echoes are the sweep.
    weather = replace(
        lidar_weather("snow"), extinction_per_m=50.0, snow_bank_width_m=0.0, snow_cover_lane_m=0.0
    )
    sim = LidarSimulator(flat_scene([]), RIG, weather, 0, GEOM)
    sweep, truth = sim.sweep_with_truth(
        RIG[0].sensor_id, Stamp(0), EgoTrack.constant(0, 0.0, 0.0, 0.0), DynamicObjects.empty(), 0
    )
    assert truth is not None and len(truth.label) > 0
    assert np.all(truth.label == PointLabel.WEATHER_NOISE)
    assert np.all(np.diff(sweep.points[:, 5]) >= 0)  # still in firing order
