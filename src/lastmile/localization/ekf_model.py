"""The pose EKF's state layout, its process model (motion and noise) and its Kalman update."""

from __future__ import annotations

import math

import numpy as np

from lastmile.core.geometry import wrap_angle_rad
from lastmile.localization.ekf_config import PoseEkfConfig

STATE_NAMES = (
    "x_m",
    "y_m",
    "yaw_rad",
    "speed_mps",
    "gyro_bias_radps",
    "accel_bias_mps2",
    "odom_scale_error",
    "gnss_error_east_m",
    "gnss_error_north_m",
    "gyro_scale_error",
)
X, Y, YAW, V, BG, BA, K, GE, GN, GS = range(10)
N_STATES = len(STATE_NAMES)
_EYE = np.eye(N_STATES)


def motion(
    c: PoseEkfConfig, state: np.ndarray, w_in: float, a_in: float, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The predicted state (GNSS error not yet faded), the Jacobian F and the process noise diagonal.

    Args:
        c: the error model.
        state: (10,) the state before, in ``STATE_NAMES`` order.
        w_in: the held IMU yaw rate (bias and scale error included), rad/s.
        a_in: the held longitudinal acceleration, m/s^2; NaN: no accelerometer.
        dt: step, s (negative to look into the past).
    """
    x, y, yaw, v, bg, ba, k, ge, gn, gs = state.tolist()
    has_accel = not math.isnan(a_in)
    # The gyro reads (1 + scale error) x rate + bias; to first order in the scale error:
    w = (w_in - bg) * (1.0 - gs)
    acc = a_in - ba if has_accel else 0.0
    v_mid = v + 0.5 * acc * dt
    mid = yaw + 0.5 * w * dt
    cs, sn = math.cos(mid), math.sin(mid)
    lever = c.zero_slip_offset_m
    vx = v_mid * cs + w * lever * sn
    vy = v_mid * sn - w * lever * cs
    adt = abs(dt)
    decay = math.exp(-abs(v) * adt / c.road_grade_length_m)
    f = _EYE.copy()
    f[0, 2], f[1, 2] = -vy * dt, vx * dt
    f[0, 3], f[1, 3] = cs * dt, sn * dt
    dx_dw = (-0.5 * vy * dt + lever * sn) * dt
    dy_dw = (0.5 * vx * dt - lever * cs) * dt
    dw_dbg, dw_dgs = -(1.0 - gs), -(w_in - bg)
    f[0, 4], f[1, 4], f[2, 4] = dx_dw * dw_dbg, dy_dw * dw_dbg, dt * dw_dbg
    f[0, 9], f[1, 9], f[2, 9] = dx_dw * dw_dgs, dy_dw * dw_dgs, dt * dw_dgs
    if has_accel:
        f[0, 5], f[1, 5] = -0.5 * cs * dt * dt, -0.5 * sn * dt * dt
        f[3, 5] = -dt
    f[5, 5] = decay
    f[5, 3] = -math.copysign(1.0, v) * adt / c.road_grade_length_m * decay * ba
    tau = c.turn_correlation_s
    q_pos = (c.pos_noise_mps**2 + (c.side_slip_ratio * v) ** 2 * tau) * adt
    if has_accel:
        q_v = (c.accel_noise_mps2**2 + (c.pitch_gradient * acc) ** 2 * tau) * adt
    else:
        q_v = c.speed_walk_mps2**2 * adt
    q = np.array(
        (
            q_pos,
            q_pos,
            c.gyro_noise_radps**2 * adt,
            q_v,
            c.yaw_rate_bias_walk_radps**2 * adt,
            c.grade_accel_std_mps2**2 * (1.0 - decay * decay),
            c.odom_scale_walk**2 * adt,
            0.0,
            0.0,
            0.0,
        )
    )
    s = np.array(
        (
            x + vx * dt,
            y + vy * dt,
            wrap_angle_rad(yaw + w * dt),
            v + acc * dt,
            bg,
            ba * decay,
            k,
            ge,
            gn,
            gs,
        )
    )
    return s, f, q


def kalman_update(
    s: np.ndarray, p: np.ndarray, h: np.ndarray, innovation: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update (closed-form inverse for 1 and 2 rows), kept symmetric."""
    ph = p @ h.T
    cov = h @ ph + r
    if cov.shape == (1, 1):
        inv = np.array([[1.0 / cov[0, 0]]])
    elif cov.shape == (2, 2):
        a, b, c, d = cov[0, 0], cov[0, 1], cov[1, 0], cov[1, 1]
        inv = np.array([[d, -b], [-c, a]]) / (a * d - b * c)
    else:
        inv = np.linalg.inv(cov)
    gain = ph @ inv
    new_p = p - gain @ ph.T
    return s + gain @ innovation, 0.5 * (new_p + new_p.T)
