"""Pose EKF: wheel odometry and IMU yaw rate predict, RTK GNSS/INS corrects (gated).

State: x_m, y_m, yaw_rad of the rear axle in the map frame. Speed and yaw rate come straight from the
odometry and the IMU. Written with plain floats: it runs at 50 Hz inside a loop that must be much
faster than real time, where 3x3 NumPy calls would cost more than the arithmetic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import MessageError
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import LocalizationEstimate


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseEkfConfig:
    """Noise and integrity parameters.

    Attributes:
        speed_noise_mps: odometry speed noise (one sigma) driving position uncertainty growth.
        yaw_rate_noise_radps: IMU yaw-rate noise (one sigma).
        gate_chi2: chi-square bound (2 dof position) beyond which a GNSS fix is rejected as an outlier;
            13.8 is the 0.999 quantile.
        max_pos_std_m: the estimate is marked invalid once its position sigma exceeds this.
    """

    speed_noise_mps: float = 0.05
    yaw_rate_noise_radps: float = 0.01
    gate_chi2: float = 13.8
    max_pos_std_m: float = 1.0


class PoseEkf:
    """Extended Kalman filter over (x, y, yaw); covariance kept as a symmetric 3x3 in floats."""

    def __init__(self, config: PoseEkfConfig | None = None) -> None:
        self.config = config or PoseEkfConfig()
        self.x = self.y = self.yaw = 0.0
        self.speed = 0.0
        self.yaw_rate = 0.0
        self.p = [[1e6, 0.0, 0.0], [0.0, 1e6, 0.0], [0.0, 0.0, 10.0]]
        self.stamp_us: int | None = None
        self.initialised = False
        self.rejected = 0

    def predict(self, stamp: Stamp, speed_mps: float, yaw_rate_radps: float) -> None:
        """Dead-reckon to ``stamp`` with the last inputs, then take the new ones."""
        if not (math.isfinite(speed_mps) and math.isfinite(yaw_rate_radps)):
            raise MessageError(f"PoseEkf.predict: expected finite inputs, got {speed_mps}, {yaw_rate_radps}")
        self._propagate(int(stamp))
        self.speed, self.yaw_rate = speed_mps, yaw_rate_radps

    def _propagate(self, t_us: int) -> None:
        if self.stamp_us is None:
            self.stamp_us = t_us
            return
        dt = (t_us - self.stamp_us) / 1e6
        if dt <= 0.0:
            return  # an older input: the state is already past it
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        v = self.speed
        self.x += v * c * dt
        self.y += v * s * dt
        self.yaw = wrap_angle_rad(self.yaw + self.yaw_rate * dt)
        # P = F P F^T + Q, F = [[1,0,-v s dt],[0,1,v c dt],[0,0,1]], Q = G diag(qv, qw) G^T.
        a, b = -v * s * dt, v * c * dt
        p = self.p
        p00 = p[0][0] + 2 * a * p[0][2] + a * a * p[2][2]
        p01 = p[0][1] + a * p[1][2] + b * p[0][2] + a * b * p[2][2]
        p02 = p[0][2] + a * p[2][2]
        p11 = p[1][1] + 2 * b * p[1][2] + b * b * p[2][2]
        p12 = p[1][2] + b * p[2][2]
        p22 = p[2][2]
        qv = (self.config.speed_noise_mps * dt) ** 2
        qw = (self.config.yaw_rate_noise_radps * dt) ** 2
        p00 += c * c * qv
        p01 += c * s * qv
        p11 += s * s * qv
        p22 += qw
        self.p = [[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]]
        self.stamp_us = t_us

    def update_gnss(self, frame: GnssInsFrame) -> bool:
        """Correct with a GNSS/INS fix; returns False when it was rejected or had no fix."""
        frame.validate()
        if not frame.fix_ok:
            return False
        if not self.initialised:
            self.x, self.y, self.yaw = frame.x_m, frame.y_m, frame.yaw_rad
            r = frame.pos_std_m**2
            self.p = [[r, 0.0, 0.0], [0.0, r, 0.0], [0.0, 0.0, frame.yaw_std_rad**2]]
            self.stamp_us = max(self.stamp_us or 0, int(frame.stamp))
            self.initialised = True
            return True
        # A fix older than the filter is applied as if current: at 20 km/h and 30 ms latency the
        # shuttle moved about 0.17 m, so the fix is first shifted along the heading by that motion.
        lag_s = max(0.0, ((self.stamp_us or 0) - int(frame.stamp)) / 1e6)
        zx = frame.x_m + self.speed * lag_s * math.cos(self.yaw)
        zy = frame.y_m + self.speed * lag_s * math.sin(self.yaw)
        zyaw = frame.yaw_rad + self.yaw_rate * lag_s
        r_pos, r_yaw = frame.pos_std_m**2, frame.yaw_std_rad**2
        p = self.p
        dx, dy = zx - self.x, zy - self.y
        s00, s01, s11 = p[0][0] + r_pos, p[0][1], p[1][1] + r_pos
        det = s00 * s11 - s01 * s01
        d2 = (s11 * dx * dx - 2 * s01 * dx * dy + s00 * dy * dy) / det
        if d2 > self.config.gate_chi2:
            self.rejected += 1
            return False
        # Position and yaw measured directly (H = I); a 3x3 solve only on GNSS fixes (10 Hz).
        pm = np.array(p)
        s_mat = pm + np.diag([r_pos, r_pos, r_yaw])
        k = pm @ np.linalg.inv(s_mat)
        innov = np.array([dx, dy, wrap_angle_rad(zyaw - self.yaw)])
        state = np.array([self.x, self.y, self.yaw]) + k @ innov
        self.x, self.y, self.yaw = float(state[0]), float(state[1]), wrap_angle_rad(float(state[2]))
        pn = (np.eye(3) - k) @ pm
        self.p = ((pn + pn.T) / 2).tolist()
        return True

    def estimate(self, stamp: Stamp) -> LocalizationEstimate:
        """The pose extrapolated to ``stamp`` (not stored), with validity from the covariance."""
        dt = 0.0 if self.stamp_us is None else max(0.0, (int(stamp) - self.stamp_us) / 1e6)
        yaw = self.yaw + self.yaw_rate * dt
        x = self.x + self.speed * math.cos(self.yaw) * dt
        y = self.y + self.speed * math.sin(self.yaw) * dt
        pos_std = math.sqrt(max(self.p[0][0], self.p[1][1]))
        return LocalizationEstimate(
            stamp=stamp,
            map_from_base=SE2(x, y, wrap_angle_rad(yaw)),
            speed_mps=self.speed,
            yaw_rate_radps=self.yaw_rate,
            pos_std_m=pos_std,
            yaw_std_rad=math.sqrt(self.p[2][2]),
            valid=self.initialised and pos_std <= self.config.max_pos_std_m,
        )
