"""A simulated camera-LiDAR calibration session for the tests (``sim/calibration_target.py``)."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from lastmile.localization.camera_mount_file import MountPose, camera_from_parent
from lastmile.localization.checkerboard_detection import CameraIntrinsics, Checkerboard
from lastmile.localization.lidar_calibration import mount_difference
from lastmile.sim.calibration_target import PROJECT_CAMERA, BoardSpec, board_poses, simulate_session

BOARD_SPEC = BoardSpec()
BOARD = Checkerboard(cols=BOARD_SPEC.cols, rows=BOARD_SPEC.rows, square_m=BOARD_SPEC.square_m)
INTRINSICS = CameraIntrinsics(
    fx_px=PROJECT_CAMERA.fx_px,
    fy_px=PROJECT_CAMERA.fy_px,
    cx_px=PROJECT_CAMERA.cx_px,
    cy_px=PROJECT_CAMERA.cy_px,
    width_px=PROJECT_CAMERA.width_px,
    height_px=PROJECT_CAMERA.height_px,
)
TRUE_IN_LIDAR = MountPose(
    x_m=0.12,
    y_m=-0.08,
    z_m=-0.25,
    roll_rad=math.radians(0.5),
    pitch_rad=math.radians(3.0),
    yaw_rad=math.radians(-1.0),
)
TRUTH = camera_from_parent(TRUE_IN_LIDAR)
"""(4, 4) the true camera_from_lidar."""


def perturbed(camera_from_lidar: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The camera moved 0.2 m and turned 2 degrees along and about random directions."""
    lidar_from_camera = np.linalg.inv(camera_from_lidar)
    direction = rng.normal(size=3)
    axis = rng.normal(size=3)
    turn = Rotation.from_rotvec(math.radians(2.0) * axis / np.linalg.norm(axis)).as_matrix()
    lidar_from_camera[:3, :3] = turn @ lidar_from_camera[:3, :3]
    lidar_from_camera[:3, 3] += 0.2 * direction / np.linalg.norm(direction)
    return np.linalg.inv(lidar_from_camera)


def error_cm_deg(truth: np.ndarray, estimate: np.ndarray) -> tuple[float, float]:
    """Distance (cm) and angle (deg) between two camera_from_lidar, as camera poses in the LiDAR frame."""
    m, rad = mount_difference(np.linalg.inv(truth), np.linalg.inv(estimate))
    return m * 100.0, math.degrees(rad)


def session(
    seed: int, views: int, sweeps: int = 1, tilt_rad: tuple[float, float, float] | None = None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(image, cloud) per view: boards 2.5-4.5 m ahead, the true mount."""
    rng = np.random.default_rng(seed)
    kwargs = {} if tilt_rad is None else {"tilt_rad": tilt_rad}
    poses = board_poses(rng, views, BOARD_SPEC, distance_m=(2.5, 4.5), **kwargs)
    return simulate_session(rng, poses, TRUTH, BOARD_SPEC, sweeps_per_view=sweeps)
