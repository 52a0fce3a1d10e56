"""LiDAR calibration on the simulator's own LiDAR model: the default rig's front and left units.

The 32-channel front unit (rear half blocked by the body) and the 16-channel left blind-spot unit see a
wall corner ahead on the left (Snow Lion's target: two walls and the ground) in a flat world, standing
still (``benchmarks/lidar_calibration.py`` runs both side units over seeds). Their sweeps have the
model's ring pattern, 2 cm range noise and their own beams, so no point is shared. The left unit's
nominal mount is 0.2 m and 2 degrees off.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.errors import CalibrationError
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.localization.lidar_calibration import calibrate_by_icp, calibrate_by_planes, mount_difference
from lastmile.sim.lidar import LidarSimulator
from lastmile.sim.lidar_rig import EgoTrack, default_lidar_rig
from lastmile.sim.lidar_scene import (
    REFLECTIVITY,
    Cylinders,
    DynamicObjects,
    PointLabel,
    Segments,
    StaticLidarScene,
)
from lastmile.sim.lidar_weather import LidarWeather

from .lidar_scene import perturbed

GEOMETRY = VehicleGeometry()
RIG = {spec.sensor_id: spec for spec in default_lidar_rig(GEOMETRY)}
# Walls (x0, y0, x1, y1), 3 m high: one along the road 6 m to each side, one across it 12 m ahead; a
# wall corner ahead on the left and one on the right.
CORNER = ((2.0, 6.0, 12.0, 6.0), (12.0, 6.0, 12.0, -6.0), (12.0, -6.0, 2.0, -6.0))


def corner_scene() -> StaticLidarScene:
    ends = np.array(CORNER, dtype=float)
    n = len(ends)
    label = np.full(n, int(PointLabel.BUILDING), dtype=np.int8)
    walls = Segments(
        p0=ends[:, :2],
        p1=ends[:, 2:],
        z_min_m=np.zeros(n),
        z_max_m=np.full(n, 3.0),
        label=label,
        reflectivity=np.full(n, REFLECTIVITY[PointLabel.BUILDING]),
        retro=np.zeros(n, dtype=bool),
    )
    empty = DynamicObjects.empty().cylinders
    cylinders = Cylinders(**{f: getattr(empty, f) for f in Cylinders.__dataclass_fields__})
    return StaticLidarScene(segments=walls, cylinders=cylinders, ground=None)


@pytest.fixture(scope="module")
def sweeps() -> tuple[np.ndarray, np.ndarray]:
    """The front unit's sweep in the base frame, the left unit's in its own frame."""
    lidar = LidarSimulator(corner_scene(), tuple(RIG.values()), LidarWeather(), 0, GEOMETRY)
    still = EgoTrack.constant(0, 0.0, 0.0, 0.0)
    front = lidar.sweep("front", Stamp(0), still, DynamicObjects.empty(), 0)
    left = lidar.sweep("left", Stamp(0), still, DynamicObjects.empty(), 0)
    mount = RIG["front"].base_from_sensor
    ref = front.points[:, :3].astype(np.float64) @ mount[:3, :3].T + mount[:3, 3]
    return ref, left.points[:, :3].astype(np.float64)


def test_three_planes_recover_the_left_unit_within_2_cm_and_01_deg(sweeps) -> None:
    ref, left = sweeps
    truth = RIG["left"].base_from_sensor
    result = calibrate_by_planes(ref, left, perturbed(truth, 0.2, 2.0), RIG["front"].base_from_sensor[:3, 3])
    shift_m, turn_rad = mount_difference(truth, result.base_from_sensor)
    assert shift_m < 0.02
    assert math.degrees(turn_rad) < 0.1
    assert result.rmse_m < 0.03  # the model's 2 cm range noise


def test_nearest_neighbour_icp_refuses_the_ring_pattern_rather_than_answer_wrong(sweeps) -> None:
    # On 16 rings the ground's neighbourhoods are lines and their normals arbitrary: point-to-plane
    # ICP settles centimetres and half a degree off. It must say so, not return that mount.
    ref, left = sweeps
    with pytest.raises(CalibrationError, match="icp calibration"):
        calibrate_by_icp(ref, left, perturbed(RIG["left"].base_from_sensor, 0.2, 2.0))
