"""A synthetic drive with the error sources a real one has, independent of the EKF's own error model.

Truth at 100 Hz: stops, drive-offs at 1 m/s^2, 5 m/s cruising, 20 m radius turns both ways, over a
rolling road (grade 5 % amplitude, 150 m wavelength). IMU: gyro with a constant 0.2 deg/s bias, a
0.5 % scale error and white noise; accelerometer reading gravity on the grade, body pitch under
acceleration (1.5 deg per g), a 0.05 m/s^2 bias and vibration. RTK: 4 Hz fixes of an antenna 1.2 m
ahead of the rear axle, 1 cm white noise plus a slowly wandering 1 cm error, reporting an optimistic
formal sigma of 5 mm. Wheel speed (optional) 50 Hz with a 1.5 % scale error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.gnss_messages import GnssFix, GnssQuality
from lastmile.core.stamp import stamp_from_s

G = 9.80665
LEVER = (1.2, 0.0)


@dataclass
class Drive:
    t_s: np.ndarray  # (N,) 100 Hz
    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray
    speed_mps: np.ndarray
    gyro_radps: np.ndarray
    accel_mps2: np.ndarray
    wheel_mps: np.ndarray
    fixes: list[GnssFix]  # 4 Hz, antenna


def _profile(duration_s: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speed, acceleration and yaw rate: a repeated cycle of stop, drive-off, cruise and turns."""
    n = int(duration_s / dt)
    t = np.arange(n) * dt
    speed = np.zeros(n)
    v = 0.0
    cycle = 70.0
    for i, ti in enumerate(t):
        phase = ti % cycle
        target = 0.0 if phase < 5.0 or phase > 62.0 else 5.0
        step = 1.0 * dt
        v = min(v + step, target) if v < target else max(v - step, target)
        speed[i] = v
    accel = np.gradient(speed, dt)
    yaw_rate = np.zeros(n)
    for start, sign in ((15.0, 1.0), (30.0, -1.0), (45.0, 1.0)):
        phase = t % cycle
        turning = (phase >= start) & (phase < start + 6.0)
        yaw_rate[turning] = sign * speed[turning] / 20.0
    return speed, accel, yaw_rate


def make_drive(duration_s: float = 300.0, seed: int = 7) -> Drive:
    dt = 0.01
    rng = np.random.default_rng(seed)
    speed, accel, yaw_rate = _profile(duration_s, dt)
    n = speed.size
    t = np.arange(n) * dt
    yaw = np.cumsum(yaw_rate) * dt
    x = np.cumsum(speed * np.cos(yaw)) * dt
    y = np.cumsum(speed * np.sin(yaw)) * dt
    dist = np.cumsum(speed) * dt
    grade = 0.05 * np.sin(2 * math.pi * dist / 150.0)
    pitch = 1.5 * math.pi / 180.0 * accel / G
    gyro = yaw_rate * 1.005 + 0.2 * math.pi / 180.0 + rng.normal(0.0, 0.01 * math.pi / 180 * 10.0, n)
    accel_meas = accel + G * grade + G * pitch + 0.05 + rng.normal(0.0, 0.05, n)
    wheel = speed * 1.015 + rng.normal(0.0, 0.02, n)
    fixes = []
    wander = np.zeros(2)
    for i in range(0, n, 25):
        wander = 0.98 * wander + rng.normal(0.0, 0.01 * math.sqrt(1 - 0.98**2), 2)
        cs, sn = math.cos(yaw[i]), math.sin(yaw[i])
        ax = x[i] + cs * LEVER[0] - sn * LEVER[1] + wander[0] + rng.normal(0.0, 0.01)
        ay = y[i] + sn * LEVER[0] + cs * LEVER[1] + wander[1] + rng.normal(0.0, 0.01)
        fixes.append(
            GnssFix(
                stamp=stamp_from_s(t[i]),
                x_m=ax,
                y_m=ay,
                var_xx_m2=0.005**2,
                var_xy_m2=0.0,
                var_yy_m2=0.005**2,
                quality=GnssQuality.RTK_FIXED,
            )
        )
    return Drive(t, x, y, yaw, speed, gyro, accel_meas, wheel, fixes)
