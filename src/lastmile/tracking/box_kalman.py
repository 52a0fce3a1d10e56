"""Batched linear Kalman filter for 3D box tracks: position, velocity, heading and turn rate.

State per track (7): ``x_m, y_m, z_m, yaw_rad, vx_mps, vy_mps, yaw_rate_radps``. Ground-plane motion is
constant velocity (white acceleration, per-track ``accel_std``); the heading integrates a turn rate that
is itself a random walk (white angular acceleration ``yaw_accel_std``), so a turning vehicle's box keeps
turning through a missed frame. z is a random walk. Measurements: the box centre and heading, plus the
over-ground velocity when a radar's Doppler velocity came with the box.

Heading is an angle: before an update the measured heading is flipped by pi when it disagrees with the
prediction by more than pi/2 (LiDAR detectors often confuse front and back), and the innovation is
wrapped. All tracks are predicted and updated with a few batched NumPy calls.
"""

from __future__ import annotations

import numpy as np

from lastmile.core.box3d import wrap_angle

STATE_DIM = 7
_POS = np.array([0, 1, 3])  # x, y, yaw ...
_RATE = np.array([4, 5, 6])  # ... and their rates
_POS_YAW = np.array([0, 1, 2, 3])
_POS_YAW_VEL = np.array([0, 1, 2, 3, 4, 5])


def predict(
    x: np.ndarray, p: np.ndarray, dt_s: np.ndarray, accel_std: np.ndarray, yaw_accel_std: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Predict states (N, 7) and covariances (N, 7, 7) by ``dt_s`` (N,) each; returns new arrays.

    A negative ``dt_s`` retrodicts the mean; the process noise is added with |dt| so the covariance
    still grows (uncertainty never shrinks without a measurement).
    """
    n = x.shape[0]
    if n == 0:
        return x.copy(), p.copy()
    # F = I + dt (e_0 e_4' + e_1 e_5' + e_3 e_6'): apply it by rows (F P), then by columns (F P F').
    xn = x.copy()
    xn[:, _POS] += dt_s[:, None] * x[:, _RATE]
    xn[:, 3] = wrap_angle(xn[:, 3])
    fp = p.copy()
    fp[:, _POS, :] += dt_s[:, None, None] * p[:, _RATE, :]
    pn = fp.copy()
    pn[:, :, _POS] += dt_s[:, None, None] * fp[:, :, _RATE]
    adt = np.abs(dt_s)
    qa = accel_std**2
    qw = yaw_accel_std**2
    d2, d3, d4 = adt**2, adt**3 / 2.0, adt**4 / 4.0
    for pos, vel, q in ((0, 4, qa), (1, 5, qa), (3, 6, qw)):
        pn[:, pos, pos] += q * d4
        pn[:, pos, vel] += q * d3
        pn[:, vel, pos] += q * d3
        pn[:, vel, vel] += q * d2
    pn[:, 2, 2] += 0.1 * adt  # z drifts slowly (ground slope), 0.1 m^2/s
    return xn, pn


def update(
    x: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    r_diag: np.ndarray,
    with_velocity: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Update states (N, 7) with measurements ``z`` (N, 4) or (N, 6) (with velocity); returns new arrays.

    Args:
        x: states.
        p: covariances (N, 7, 7).
        z: ``x, y, z, yaw`` (and ``vx, vy`` with ``with_velocity``) per track.
        r_diag: (N, 4) or (N, 6) measurement variances.
        with_velocity: whether ``z`` carries a velocity.
    """
    if x.shape[0] == 0:
        return x.copy(), p.copy()
    idx = _POS_YAW_VEL if with_velocity else _POS_YAW
    z = z.copy()
    # Orientation flip: a heading off by more than 90 degrees is the same box seen back to front.
    diff = wrap_angle(z[:, 3] - x[:, 3])
    flip = np.abs(diff) > 0.5 * np.pi
    z[flip, 3] = wrap_angle(z[flip, 3] + np.pi)
    innov = z - x[:, idx]
    innov[:, 3] = wrap_angle(innov[:, 3])
    ph = p[:, :, idx]  # P H^T, (N, 7, m)
    s = ph[:, idx, :] + np.einsum("ni,ij->nij", r_diag, np.eye(idx.size))
    k = np.linalg.solve(s, np.transpose(ph, (0, 2, 1)))  # (N, m, 7) = S^-1 H P
    k = np.transpose(k, (0, 2, 1))  # (N, 7, m)
    xn = x + np.einsum("nij,nj->ni", k, innov)
    xn[:, 3] = wrap_angle(xn[:, 3])
    pn = p - k @ np.transpose(ph, (0, 2, 1))
    pn = 0.5 * (pn + np.transpose(pn, (0, 2, 1)))
    return xn, pn
