"""GNSS-denied localization on mapped poles and facades (WATonoBus) through the pose EKF."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.stamp import stamp_from_s
from lastmile.core.vehicle_messages import PositionSource
from lastmile.localization.ekf import PoseEkf, PoseEkfConfig
from lastmile.localization.landmark_localization import (
    FacadeDetections,
    MapLandmarks,
    PoleDetections,
    ScanMatchPose,
)

from .synthetic_drive import LEVER, make_drive

CONFIG = PoseEkfConfig(antenna_lever_arm_m=LEVER, zero_slip_offset_m=0.0)


def _poles_along(drive, spacing_m=25.0, offset_m=6.0):
    """Light poles every ``spacing_m`` of path, alternating sides, ``offset_m`` from the path."""
    dist = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(drive.x_m), np.diff(drive.y_m)))])
    poles, side = [], 1.0
    for d in np.arange(10.0, dist[-1], spacing_m):
        i = int(np.searchsorted(dist, d))
        yaw = drive.yaw_rad[i]
        poles.append(
            (drive.x_m[i] - side * offset_m * math.sin(yaw), drive.y_m[i] + side * offset_m * math.cos(yaw))
        )
        side = -side
    return np.unique(np.round(np.array(poles), 3), axis=0)


def _run(drive, landmarks, outage, with_poles, rng):
    ekf = PoseEkf(CONFIG)
    fixes, k = drive.fixes, 0
    lateral, nees = [], []
    for i, t in enumerate(drive.t_s):
        stamp = stamp_from_s(t)
        ekf.imu(stamp, float(drive.gyro_radps[i]), float(drive.accel_mps2[i]))
        if i % 2 == 0:
            ekf.wheel_speed(stamp, float(drive.wheel_mps[i]))
        while k < len(fixes) and fixes[k].stamp <= stamp:
            if not outage[0] <= fixes[k].stamp / 1e6 < outage[1]:
                ekf.update_position(fixes[k])
            k += 1
        if with_poles and i % 10 == 0 and ekf.estimate(stamp).valid:
            c, s = math.cos(drive.yaw_rad[i]), math.sin(drive.yaw_rad[i])
            rel = landmarks.poles - (drive.x_m[i], drive.y_m[i])
            base = rel @ np.array([[c, -s], [s, c]])  # map -> base
            seen = base[(np.hypot(*base.T) < 30.0)]
            if seen.size:
                det = seen + rng.normal(0.0, 0.05, seen.shape)
                ekf.update_pose(PoleDetections(stamp=stamp, points_base=det, std_m=0.05, landmarks=landmarks))
        if outage[0] <= t < outage[1] and i % 10 == 0:
            post = ekf.posterior(stamp)
            err = post.state[:2] - (drive.x_m[i], drive.y_m[i])
            yaw = drive.yaw_rad[i]
            lateral.append(abs(-err[0] * math.sin(yaw) + err[1] * math.cos(yaw)))
            nees.append(float(err @ np.linalg.solve(post.covariance[:2, :2], err)))
    return ekf, np.array(lateral), np.array(nees)


@pytest.fixture(scope="module")
def drive():
    return make_drive(160.0)


def test_poles_hold_the_lateral_error_within_ten_centimetres_through_a_sixty_second_outage(drive):
    landmarks = MapLandmarks(poles=_poles_along(drive), segments=np.zeros((0, 2, 2)))
    rng = np.random.default_rng(1)
    ekf, lateral, nees = _run(drive, landmarks, (90.0, 150.0), True, rng)
    _, lateral_dr, _ = _run(drive, landmarks, (90.0, 150.0), False, rng)
    assert np.percentile(lateral, 95) <= 0.10
    assert np.percentile(lateral_dr, 95) > 2 * np.percentile(lateral, 95)  # dead reckoning beside it
    assert np.mean(nees <= 5.991) >= 0.9
    assert ekf.rejected_pose_measurements <= 0.02 * 600


def test_a_pole_between_two_mapped_poles_is_not_associated():
    landmarks = MapLandmarks(poles=np.array([[10.0, 3.0], [10.0, 3.6]]), segments=np.zeros((0, 2, 2)))
    det = PoleDetections(
        stamp=stamp_from_s(0.0), points_base=np.array([[10.0, 3.3]]), std_m=0.1, landmarks=landmarks
    )
    assert det.linearize(np.zeros(3), np.diag([0.04, 0.04, 1e-4])) is None
    single = MapLandmarks(poles=np.array([[10.0, 3.0]]), segments=np.zeros((0, 2, 2)))
    det = PoleDetections(
        stamp=stamp_from_s(0.0), points_base=np.array([[10.0, 3.1]]), std_m=0.1, landmarks=single
    )
    nu, h, r = det.linearize(np.zeros(3), np.diag([0.04, 0.04, 1e-4]))
    assert nu == pytest.approx([0.0, -0.1]) and h.shape == (2, 3) and r.shape == (2, 2)


def test_one_facade_constrains_the_distance_to_it_and_the_heading_not_the_position_along_it():
    # A facade along the map x axis at y = 8; the vehicle at the origin heading along x sees it 8 m left.
    landmarks = MapLandmarks(poles=np.zeros((0, 2)), segments=np.array([[[-50.0, 8.0], [50.0, 8.0]]]))
    ekf = PoseEkf(PoseEkfConfig(zero_slip_offset_m=0.0))
    from lastmile.core.sensor_frames import GnssInsFrame

    ekf.predict(stamp_from_s(0.0), 0.0, 0.0)
    ekf.update_gnss(
        GnssInsFrame(
            stamp=stamp_from_s(0.0),
            x_m=0.0,
            y_m=0.0,
            yaw_rad=0.0,
            speed_mps=0.0,
            pos_std_m=1.0,
            yaw_std_rad=0.05,
        )
    )
    before = ekf.posterior(stamp_from_s(0.0)).covariance
    facade = FacadeDetections(
        stamp=stamp_from_s(0.0),
        lines_base=np.array([[7.7, math.pi / 2]]),  # it looks 30 cm closer: we are 30 cm further left
        distance_std_m=0.03,
        angle_std_rad=0.005,
        landmarks=landmarks,
    )
    assert ekf.update_pose(facade)
    post = ekf.posterior(stamp_from_s(0.0))
    assert post.state[1] == pytest.approx(0.3, abs=0.02)
    assert math.sqrt(post.covariance[1, 1]) < 0.05  # across the facade: centimetres
    assert post.covariance[0, 0] == pytest.approx(before[0, 0], rel=0.01)  # along it: unchanged


def test_a_scan_match_with_its_covariance_is_a_direct_pose_measurement():
    ekf = PoseEkf(PoseEkfConfig(zero_slip_offset_m=0.0))
    from lastmile.core.sensor_frames import GnssInsFrame

    ekf.predict(stamp_from_s(0.0), 0.0, 0.0)
    ekf.update_gnss(
        GnssInsFrame(
            stamp=stamp_from_s(0.0),
            x_m=0.0,
            y_m=0.0,
            yaw_rad=0.0,
            speed_mps=0.0,
            pos_std_m=0.5,
            yaw_std_rad=0.05,
        )
    )
    match = ScanMatchPose(
        stamp=stamp_from_s(0.0), x_m=0.4, y_m=-0.2, yaw_rad=0.01, covariance=np.diag([1e-4, 1e-4, 1e-6])
    )
    assert ekf.update_pose(match)
    est = ekf.estimate(stamp_from_s(0.0))
    assert (est.map_from_base.x_m, est.map_from_base.y_m) == pytest.approx((0.4, -0.2), abs=0.01)
    far = ScanMatchPose(
        stamp=stamp_from_s(0.0), x_m=20.0, y_m=0.0, yaw_rad=0.0, covariance=np.diag([1e-4, 1e-4, 1e-6])
    )
    assert not ekf.update_pose(far) and ekf.rejected_pose_measurements == 1


def test_through_an_outage_the_estimate_says_landmarks_hold_it_or_that_it_dead_reckons(drive):
    landmarks = MapLandmarks(poles=_poles_along(drive), segments=np.zeros((0, 2, 2)))
    rng = np.random.default_rng(2)
    end = stamp_from_s(float(drive.t_s[-1]))
    with_poles, _, _ = _run(drive, landmarks, (120.0, 1e9), True, rng)
    without, _, _ = _run(drive, landmarks, (120.0, 1e9), False, rng)
    assert with_poles.estimate(end).source is PositionSource.LANDMARKS
    assert without.estimate(end).source is PositionSource.DEAD_RECKONING
    assert without.estimate(stamp_from_s(119.5)).source is PositionSource.GNSS
