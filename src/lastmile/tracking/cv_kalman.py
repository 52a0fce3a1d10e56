"""Constant-velocity Kalman filter for many planar tracks at once, measuring position and velocity.

Every track's state is (x, y, vx, vy). With a white-acceleration model that treats both axes alike,
an isotropic measurement noise and an isotropic start, the x axis (x, vx) and the y axis (y, vy) never
correlate and always share the same 2x2 covariance. Each track therefore carries only three numbers,
``(pp, pv, vv)``: position variance, position-velocity covariance and velocity variance per axis. That
makes prediction, gating and the update a handful of vectorised NumPy operations over all tracks,
with no per-track 4x4 algebra.
"""

from __future__ import annotations

import numpy as np


def predict(
    state: np.ndarray, cov: np.ndarray, dt_s: np.ndarray, accel_var_m2ps4: float
) -> tuple[np.ndarray, np.ndarray]:
    """Move tracks by ``dt_s`` (which may be negative: a retrodiction to an older stamp).

    Args:
        state: (T, 4) x_m, y_m, vx_mps, vy_mps.
        cov: (T, 3) per-axis pp (m^2), pv (m^2/s), vv (m^2/s^2).
        dt_s: (T,) time step per track, s.
        accel_var_m2ps4: white-acceleration spectral density, (m/s^2)^2 per Hz.

    Returns:
        New (T, 4) state and (T, 3) covariance.
    """
    # Process noise depends on |dt| and the cross term on dt*|dt|: going backwards the velocity noise
    # and position noise are anti-correlated, which keeps the retrodiction exact for this model.
    adt = np.abs(dt_s)
    dt2 = dt_s * dt_s
    pp, pv, vv = cov[:, 0], cov[:, 1], cov[:, 2]
    out_state = np.empty_like(state)
    out_state[:, 0:2] = state[:, 0:2] + state[:, 2:4] * dt_s[:, None]
    out_state[:, 2:4] = state[:, 2:4]
    out_cov = np.empty_like(cov)
    out_cov[:, 0] = pp + 2.0 * dt_s * pv + dt2 * vv + accel_var_m2ps4 * dt2 * adt / 3.0
    out_cov[:, 1] = pv + dt_s * vv + accel_var_m2ps4 * dt_s * adt / 2.0
    out_cov[:, 2] = vv + accel_var_m2ps4 * adt
    return out_state, out_cov


def gate_costs(
    state: np.ndarray, cov: np.ndarray, z: np.ndarray, pos_var_m2: np.ndarray, vel_var_m2ps2: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Squared Mahalanobis distances and negative log-likelihoods of every track-detection pair.

    Args:
        state: (T, 4) predicted tracks.
        cov: (T, 3) their per-axis covariances.
        z: (D, 4) detections x_m, y_m, vx_mps, vy_mps.
        pos_var_m2: (D,) position measurement variance per detection (isotropic).
        vel_var_m2ps2: velocity measurement variance (isotropic).

    Returns:
        ``(d2, nll, dist2_m2)``, each (T, D): the 4-dof squared Mahalanobis distance, ``d2 + ln|S|``
        (comparable across tracks of different certainty) and the squared Euclidean position distance.
    """
    s00 = cov[:, 0:1] + pos_var_m2[None, :]
    s01 = cov[:, 1:2]
    s11 = cov[:, 2:3] + vel_var_m2ps2
    det = s00 * s11 - s01 * s01
    dx = z[None, :, 0] - state[:, 0:1]
    dy = z[None, :, 1] - state[:, 1:2]
    dvx = z[None, :, 2] - state[:, 2:3]
    dvy = z[None, :, 3] - state[:, 3:4]
    dist2 = dx * dx + dy * dy
    d2 = (s11 * dist2 - 2.0 * s01 * (dx * dvx + dy * dvy) + s00 * (dvx * dvx + dvy * dvy)) / det
    return d2, d2 + 2.0 * np.log(det), dist2


def update(
    state: np.ndarray, cov: np.ndarray, z: np.ndarray, pos_var_m2: np.ndarray, vel_var_m2ps2: float
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update of M tracks with one detection each (H = I: position and velocity measured).

    Args:
        state: (M, 4) predicted tracks.
        cov: (M, 3) their per-axis covariances.
        z: (M, 4) the detection assigned to each track.
        pos_var_m2: (M,) position measurement variance of each detection.
        vel_var_m2ps2: velocity measurement variance.

    Returns:
        New (M, 4) state and (M, 3) covariance.
    """
    pp, pv, vv = cov[:, 0], cov[:, 1], cov[:, 2]
    s00 = pp + pos_var_m2
    s11 = vv + vel_var_m2ps2
    inv_det = 1.0 / (s00 * s11 - pv * pv)
    # K = P S^-1 per axis, written out for the symmetric 2x2 blocks.
    k00 = (pp * s11 - pv * pv) * inv_det
    k01 = (pv * s00 - pp * pv) * inv_det
    k10 = (pv * s11 - vv * pv) * inv_det
    k11 = (vv * s00 - pv * pv) * inv_det
    innov = z - state
    out_state = np.empty_like(state)
    out_state[:, 0:2] = state[:, 0:2] + k00[:, None] * innov[:, 0:2] + k01[:, None] * innov[:, 2:4]
    out_state[:, 2:4] = state[:, 2:4] + k10[:, None] * innov[:, 0:2] + k11[:, None] * innov[:, 2:4]
    out_cov = np.empty_like(cov)
    out_cov[:, 0] = pp - (k00 * pp + k01 * pv)
    out_cov[:, 1] = pv - (k00 * pv + k01 * vv)
    out_cov[:, 2] = vv - (k10 * pv + k11 * vv)
    return out_state, out_cov
