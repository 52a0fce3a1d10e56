"""A shuttle driving a 40 m circle at 5 m/s with 50 Hz odometry and IMU and 10 Hz RTK: the harness both
pose filters' tests drive (``PoseEkf`` in test_ekf.py, ``OdometryEkf`` in test_odometry_ekf.py)."""

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.stamp import stamp_from_s

R, V = 40.0, 5.0
W = V / R
HALF_WHEELBASE = 1.45


def unicycle(t):
    """Rear axle driving a 40 m circle at 5 m/s (front steer: no side slip)."""
    return R * math.sin(W * t), R - R * math.cos(W * t), W * t


def all_wheel_steer(t):
    """Opposite-phase all-wheel steer: mid-wheelbase on the circle, rear axle slipping outwards."""
    yaw = W * t
    return (
        R * math.sin(yaw) - HALF_WHEELBASE * math.cos(yaw),
        R - R * math.cos(yaw) - HALF_WHEELBASE * math.sin(yaw),
        yaw,
    )


@dataclass
class Run:
    ekf: Any  # the filter under test: PoseEkf or OdometryEkf
    err_m: np.ndarray  # position error at every odometry step
    valid: np.ndarray
    pos_std_m: np.ndarray
    t_s: np.ndarray


def fix(t, truth, rng, sigma=0.03, jump_m=0.0, ok=True):
    x, y, yaw = truth(t)
    return GnssInsFrame(
        stamp=stamp_from_s(t),
        x_m=x + rng.normal(0, sigma) + jump_m,
        y_m=y + rng.normal(0, sigma),
        yaw_rad=yaw + rng.normal(0, 0.004),
        speed_mps=V + rng.normal(0, 0.02),
        pos_std_m=sigma,
        yaw_std_rad=0.004,
        fix_ok=ok,
    )


def run_circle(
    ekf,
    seconds,
    truth=unicycle,
    outage=None,
    jump_at_s=None,
    jump_m=10.0,
    imu_bias_radps=0.0,
    odom_scale=1.0,
    seed=1,
    lever_m=None,
):
    """Odometry and IMU at 50 Hz, GNSS at 10 Hz; a jump lasts one fix (or on, when over 50 m).
    ``lever_m``: a zero-slip point given with every odometry sample (OdometryEkf only)."""
    rng = np.random.default_rng(seed)
    err, valid, std, times = [], [], [], []
    for k in range(int(seconds * 50)):
        t = k * 0.02
        speed = V * odom_scale + rng.normal(0, 0.02)
        extra = () if lever_m is None else (lever_m,)
        ekf.predict(stamp_from_s(t), speed, W + imu_bias_radps + rng.normal(0, 0.003), *extra)
        if k % 5 == 0:
            in_outage = outage is not None and outage[0] <= t < outage[1]
            jump = 0.0
            if jump_at_s is not None and (abs(t - jump_at_s) < 1e-9 or (jump_m > 50 and t >= jump_at_s)):
                jump = jump_m
            ekf.update_gnss(fix(t, truth, rng, jump_m=jump, ok=not in_outage))
        est = ekf.estimate(stamp_from_s(t))
        x, y, _ = truth(t)
        err.append(math.hypot(est.map_from_base.x_m - x, est.map_from_base.y_m - y))
        valid.append(est.valid)
        std.append(est.pos_std_m)
        times.append(t)
    return Run(ekf, np.array(err), np.array(valid), np.array(std), np.array(times))
