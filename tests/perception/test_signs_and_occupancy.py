"""GEM's sign detection finds a facing retro-reflective plate; its height-map stop law."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.errors import MessageError
from lastmile.perception.occupancy import (
    HeightMapConfig,
    height_map,
    nearest_obstacle_on_path_m,
    obstacle_stop_speed_mps,
)
from lastmile.perception.signs import detect_sign, stop_deceleration_mps2
from tests.perception.synthetic import Box, Scene, base_cloud, default_rig


def _sign_scene(facing: bool, x: float = 12.0) -> Scene:
    if facing:  # a 0.75 m plate facing the bus (normal along -x), 2 m up, on a pole
        plate = Box((x, -3.4, 1.8), (x + 0.03, -2.65, 2.55), retro=True)
    else:  # the same plate edge-on (parallel to the road)
        plate = Box((x, -3.4, 1.8), (x + 0.75, -3.37, 2.55), retro=True)
    pole = Box((x + 0.04, -3.1, 0.0), (x + 0.1, -3.04, 1.8))
    return Scene(profile_y=(-30.0, 30.0), profile_z=(0.0, 0.0), boxes=(plate, pole))


def test_facing_retro_reflective_plate_is_detected_with_its_distance():
    xyz, inten, box = base_cloud(_sign_scene(True), default_rig()[0], np.random.default_rng(0))
    det = detect_sign(xyz, inten, np.random.default_rng(1))
    assert det is not None
    plate = box == 0
    assert np.isin(det.inlier_idx, np.flatnonzero(plate)).all()
    assert det.distance_m == pytest.approx(math.hypot(12.015, 3.025), abs=0.2)
    assert det.normal[0] <= -0.9
    assert det.stage_counts[0] > det.stage_counts[1] >= det.stage_counts[4] >= 5


def test_a_plate_not_facing_the_vehicle_is_rejected():
    xyz, inten, _ = base_cloud(_sign_scene(False), default_rig()[0], np.random.default_rng(0))
    assert detect_sign(xyz, inten, np.random.default_rng(1)) is None


def test_no_reflective_points_means_no_sign():
    xyz, inten, _ = base_cloud(_sign_scene(True), default_rig()[0], np.random.default_rng(0))
    assert detect_sign(xyz, np.minimum(inten, 60.0), np.random.default_rng(1)) is None


def test_stop_deceleration_is_v_squared_over_two_d():
    assert stop_deceleration_mps2(3.0, 10.0) == pytest.approx(-0.45)
    assert stop_deceleration_mps2(0.0, 10.0) == 0.0
    with pytest.raises(MessageError, match="distance > 0"):
        stop_deceleration_mps2(3.0, 0.0)


def test_height_map_marks_a_pedestrian_and_the_stop_law_slows_then_stops():
    ped = Box((10.0, -0.25, 0.0), (10.5, 0.25, 1.7))
    scene = Scene(profile_y=(-30.0, 30.0), profile_z=(0.0, 0.0), boxes=(ped,))
    xyz, _, _ = base_cloud(scene, default_rig()[0], np.random.default_rng(0))
    grid = height_map(xyz)
    assert grid.occupied.sum() >= 2
    d = nearest_obstacle_on_path_m(grid, 0.0)
    assert 9.5 <= d <= 10.5
    # Steering hard away (radius ~4 m) the pedestrian is off the path.
    assert nearest_obstacle_on_path_m(grid, 0.6, HeightMapConfig()) > 10.5
    assert obstacle_stop_speed_mps(d, 3.0) == pytest.approx(d / 5 - 1)
    assert obstacle_stop_speed_mps(4.0, 3.0) == 0.0
    assert obstacle_stop_speed_mps(math.inf, 3.0) == 3.0
    assert obstacle_stop_speed_mps(100.0, 3.0) == 3.0


def test_flat_ground_is_free():
    scene = Scene(profile_y=(-30.0, 30.0), profile_z=(0.0, 0.0))
    xyz, _, _ = base_cloud(scene, default_rig()[0], np.random.default_rng(0))
    assert not height_map(xyz).occupied.any()
