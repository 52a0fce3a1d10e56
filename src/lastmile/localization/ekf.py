"""Pose EKF: IMU (yaw rate, longitudinal acceleration) and wheel speed predict, GNSS corrects.

State: rear-axle x_m, y_m, yaw_rad in the map frame, speed_mps, gyro yaw-rate bias, accelerometer
bias (the road grade the accelerometer feels as gravity) and the wheel-odometry scale error. The
prediction runs on whichever inputs exist: an IMU with an accelerometer drives the speed (a wheel speed,
when present, is then a measurement of speed times scale); without an accelerometer the speed is a
random walk held by the wheel speed. Process noise is a sensor error model (``PoseEkfConfig``) in which
every correlated error grows with the time, angle or distance that excites it, so the covariance
through a GNSS outage stays honest. GNSS fixes are gated by their own reported covariance; a filter
proven wrong by consistent rejected fixes re-acquires within ``reacquire_window_s``. A short history of
inputs and posteriors lets late inputs be inserted at their stamps and the newer ones re-applied.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.stats import chi2

from lastmile.core.errors import MessageError
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.gnss_messages import (
    ACCURACY_FLOOR_M,
    ERROR_CORRELATION_S,
    GnssFix,
    GnssQuality,
    floored_sigma_m,
    white_covariance_m2,
)
from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.stamp import US_PER_S, Stamp
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.localization.ekf_config import PoseEkfConfig
from lastmile.localization.ekf_model import (
    BG,
    GE,
    GN,
    GS,
    N_STATES,
    YAW,
    K,
    V,
    X,
    Y,
    kalman_update,
    motion,
)
from lastmile.localization.landmark_localization import PoseMeasurement
from lastmile.localization.position_source import AbsoluteUpdates
from lastmile.localization.reacquisition import ReacquisitionRule, RejectedFix

__all__ = ["PoseEkf", "PoseEkfConfig", "PosePosterior"]

_SPEED_PRIOR_STD_MPS = 10.0  # a shuttle's speed range: the speed is unknown until measured
_NO_ACCEL = math.nan
_DIAG = np.diag_indices(N_STATES)
_DIAG3 = np.diag_indices(3)


class _Snap(NamedTuple):
    """Posterior after one input. ``t_us`` < 0 before the first input; arrays are never mutated."""

    t_us: int
    initialised: bool
    yaw_known: bool
    w_in: float
    a_in: float
    s: np.ndarray
    p: np.ndarray
    anchor: tuple[float, float, float] | None = None
    gnss_quality: GnssQuality | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class PosePosterior:
    """The filter's state and covariance at a stamp.

    Attributes:
        state: (10,) float64: x_m, y_m, yaw_rad, speed_mps, gyro bias rad/s, accelerometer bias m/s^2,
            wheel-odometry scale error, GNSS solution error east and north (m; its correlated part),
            gyro scale error.
        covariance: (10, 10) float64, same order.
    """

    stamp: Stamp
    state: np.ndarray
    covariance: np.ndarray
    initialised: bool
    yaw_known: bool


_ODOM, _IMU, _WHEEL, _GNSS_INS, _GNSS_POS, _POSE = range(6)
_Payload = tuple[float, float] | float | GnssInsFrame | GnssFix | PoseMeasurement


@dataclass(slots=True)
class _Event:
    t_us: int
    kind: int
    payload: _Payload
    snap: _Snap
    reset: bool = False


class PoseEkf:
    """Extended Kalman filter over (x, y, yaw, speed, gyro bias, accelerometer bias, odometry scale).

    Inputs may arrive slightly out of order: one older than the newest input is inserted at its stamp
    within ``history_s`` and every newer input is re-applied, so the result equals in-order processing.
    ``estimate`` may also be asked for a past stamp (a radar frame's capture time).
    """

    def __init__(self, config: PoseEkfConfig | None = None) -> None:
        self.config = c = config or PoseEkfConfig()
        self.absolute = AbsoluteUpdates()
        """When a fix or a landmark pose was last accepted (the estimate's ``source``)."""
        self.rejected_fixes = 0
        """Fixes rejected by the chi-square gate (each counted once, when it arrives)."""
        self.gross_rejections = 0
        """Of those, the fixes beyond ``gross_chi2``."""
        self.accepted_fixes = 0
        """Fixes used (initialisations and re-acquisitions included)."""
        self.max_rejected_chi2 = 0.0
        """The largest squared Mahalanobis distance of a rejected fix so far (for tuning reports)."""
        self.dropped_inputs = 0
        """Inputs older than the history, dropped."""
        self.resets = 0
        """Re-acquisitions: the filter re-initialised its position from consistent rejected fixes."""
        self.rejected_pose_measurements = 0
        """Pose measurements (landmarks, scan matches) beyond the chi-square gate."""
        self._reacquisition = ReacquisitionRule(
            c.reacquire_window_s, c.reacquire_min_fixes, c.reacquire_chi2_quantile
        )
        self._reset_on_arrival = False
        prior = np.diag(
            [
                0.0,
                0.0,
                math.pi**2,
                _SPEED_PRIOR_STD_MPS**2,
                c.yaw_rate_bias_std_radps**2,
                c.grade_accel_std_mps2**2,
                c.odom_scale_std**2,
                0.0,
                0.0,
                c.gyro_scale_error**2,
            ]
        )
        self._latest = _Snap(-1, False, False, 0.0, _NO_ACCEL, np.zeros(N_STATES), prior)
        self._events: list[_Event] = []
        self._history_us = round(c.history_s * US_PER_S)
        self._lever = c.antenna_lever_arm_m
        self._lever_sq = c.antenna_lever_arm_m[0] ** 2 + c.antenna_lever_arm_m[1] ** 2
        self._r_odom = c.odom_speed_std_mps**2

    # --- public API ----------------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        """Whether a GNSS fix has set the position."""
        return self._latest.initialised

    @property
    def yaw_rate_bias_radps(self) -> float:
        """Current estimate of the gyro yaw-rate bias (subtracted from every IMU reading)."""
        return float(self._latest.s[BG])

    def predict(self, stamp: Stamp, speed_mps: float, yaw_rate_radps: float) -> None:
        """Move the filter to ``stamp`` and take a new wheel speed and IMU yaw rate.

        The motion up to ``stamp`` uses the previous yaw rate (held since the last call); the speed
        is a measurement of the speed state. Equivalent to ``imu`` without an accelerometer followed
        by ``wheel_speed``; the last accelerometer reading given to ``imu`` stays in use.

        Raises:
            MessageError: a non-finite input or a negative stamp.
        """
        _check_inputs("PoseEkf.predict", stamp, speed_mps=speed_mps, yaw_rate_radps=yaw_rate_radps)
        self._insert(int(stamp), _ODOM, (speed_mps, yaw_rate_radps))

    def imu(self, stamp: Stamp, yaw_rate_radps: float, accel_x_mps2: float | None = None) -> None:
        """Move the filter to ``stamp`` on the held IMU reading, then hold this one.

        Args:
            stamp: capture time of the sample, µs.
            yaw_rate_radps: yaw rate about the vehicle's up axis, counter-clockwise positive, bias
                included.
            accel_x_mps2: specific force along the vehicle's forward axis (gravity on a slope
                included), or None when the IMU has no accelerometer: the speed is then a random walk
                held by the wheel speed.

        Raises:
            MessageError: a non-finite input or a negative stamp.
        """
        accel = _NO_ACCEL if accel_x_mps2 is None else accel_x_mps2
        _check_inputs("PoseEkf.imu", stamp, yaw_rate_radps=yaw_rate_radps, accel_x_mps2=accel_x_mps2 or 0.0)
        self._insert(int(stamp), _IMU, (yaw_rate_radps, accel))

    def wheel_speed(self, stamp: Stamp, speed_mps: float) -> None:
        """Correct with a wheel-odometry speed (rear axle, forward positive) measured at ``stamp``."""
        _check_inputs("PoseEkf.wheel_speed", stamp, speed_mps=speed_mps)
        self._insert(int(stamp), _WHEEL, speed_mps)

    def update_gnss(self, frame: GnssInsFrame) -> bool:
        """Correct with an RTK GNSS/INS solution (base position, yaw and speed, with its std devs).

        Returns:
            True if the fix was used; False when ``fix_ok`` is False, the chi-square gate rejected it
            (counted in ``rejected_fixes``) or it was older than the history (``dropped_inputs``).

        Raises:
            MessageError: a non-finite field, a non-positive std dev or a negative stamp.
        """
        frame.validate_for_fusion()
        if not frame.fix_ok:
            return False
        return self._noted(PositionSource.GNSS, frame.stamp, self._insert(int(frame.stamp), _GNSS_INS, frame))

    def update_position(self, fix: GnssFix) -> bool:
        """Correct with a position-only GNSS fix of the antenna (``antenna_lever_arm_m`` from the base).

        The fix's covariance is floored at its solution type's datasheet accuracy. Before the heading
        is known (no INS), it is initialised from the course between fixes ``heading_init_distance_m``
        apart; the estimate stays invalid until then.

        Returns:
            True if the fix was used (see ``update_gnss``).
        """
        fix.validate()
        return self._noted(PositionSource.GNSS, fix.stamp, self._insert(int(fix.stamp), _GNSS_POS, fix))

    def update_pose(
        self, measurement: PoseMeasurement, source: PositionSource = PositionSource.LANDMARKS
    ) -> bool:
        """Correct with a measurement of the planar pose (landmarks, a scan match), linearised here.

        Used only once the filter has a position and heading; gated at the 0.999 chi-square quantile
        of its dimension (rejections counted in ``rejected_pose_measurements``). An accepted one makes
        ``source`` the estimate's source (:mod:`lastmile.localization.position_source`).

        Returns:
            True if it was used.
        """
        if measurement.stamp < 0:
            raise MessageError(
                f"PoseMeasurement.stamp: expected a non-negative stamp, got {measurement.stamp}"
            )
        used = self._insert(int(measurement.stamp), _POSE, measurement)
        return self._noted(source, measurement.stamp, used)

    def _noted(self, source: PositionSource, stamp: Stamp, used: bool) -> bool:
        if used:
            self.absolute.note(source, int(stamp))
        return used

    def estimate(self, stamp: Stamp) -> LocalizationEstimate:
        """The pose at ``stamp``, extrapolated from the newest posterior at or before it.

        Nothing is stored. ``valid`` is False before the first fix, before the heading is known and
        while the position sigma exceeds ``max_pos_std_m``.
        """
        snap = self._base_at(int(stamp))
        s, p = self._propagate_pose(snap, int(stamp)) if snap.t_us >= 0 else (snap.s, snap.p[:3, :3])
        a, b, d = p[0, 0], p[0, 1], p[1, 1]
        pos_std = math.sqrt(0.5 * (a + d) + math.sqrt(0.25 * (a - d) ** 2 + b * b))
        return LocalizationEstimate(
            stamp=stamp,
            map_from_base=SE2(float(s[X]), float(s[Y]), float(s[YAW])),
            speed_mps=float(s[V]),
            yaw_rate_radps=(snap.w_in - float(s[BG])) * (1.0 - float(s[GS])),
            pos_std_m=pos_std,
            yaw_std_rad=math.sqrt(p[YAW, YAW]),
            valid=snap.initialised and snap.yaw_known and pos_std <= self.config.max_pos_std_m,
            source=self.absolute.source_at(int(stamp)),
        )

    def posterior(self, stamp: Stamp) -> PosePosterior:
        """State and full covariance at ``stamp`` (extrapolated like ``estimate``); copies."""
        snap = self._at(int(stamp))
        return PosePosterior(
            stamp=stamp,
            state=snap.s.copy(),
            covariance=snap.p.copy(),
            initialised=snap.initialised,
            yaw_known=snap.yaw_known,
        )

    # --- history and replay --------------------------------------------------------------------
    def _base_at(self, t_us: int) -> _Snap:
        """The newest posterior at or before ``t_us`` (the oldest kept, for a stamp before the history)."""
        snap = self._latest
        events = self._events
        if events and t_us < snap.t_us:
            k = len(events) - 1
            while k > 0 and events[k].t_us > t_us:
                k -= 1
            snap = events[k].snap
        return snap

    def _at(self, t_us: int) -> _Snap:
        snap = self._base_at(t_us)
        return self._propagate(snap, t_us) if snap.t_us >= 0 else snap

    def _insert(self, t_us: int, kind: int, payload: _Payload) -> bool:
        """Apply one input at its stamp, re-applying newer ones; returns whether it was used."""
        events = self._events
        if not events or t_us >= events[-1].t_us:
            snap, used = self._apply(self._latest, t_us, kind, payload, reset=False, first_time=True)
            events.append(_Event(t_us, kind, payload, snap, self._take_reset()))
            self._latest = snap
            cutoff = t_us - self._history_us
            if events[0].t_us < cutoff:
                k = 0
                while events[k].t_us < cutoff and k < len(events) - 1:
                    k += 1
                del events[:k]
            return used
        k = len(events)
        while k > 0 and events[k - 1].t_us > t_us:
            k -= 1
        if k == 0:
            self.dropped_inputs += 1
            return False
        snap, used = self._apply(events[k - 1].snap, t_us, kind, payload, reset=False, first_time=True)
        events.insert(k, _Event(t_us, kind, payload, snap, self._take_reset()))
        for event in events[k + 1 :]:
            # Replays never count, gate-reset or decide anything: a reset decided on arrival stays one.
            snap, _ = self._apply(snap, event.t_us, event.kind, event.payload, event.reset, first_time=False)
            event.snap = snap
        self._latest = snap
        return used

    def _take_reset(self) -> bool:
        reset, self._reset_on_arrival = self._reset_on_arrival, False
        return reset

    def _apply(
        self, snap: _Snap, t_us: int, kind: int, payload: _Payload, reset: bool, first_time: bool
    ) -> tuple[_Snap, bool]:
        snap = self._propagate(snap, t_us) if snap.t_us >= 0 else snap._replace(t_us=t_us)
        if kind == _ODOM:
            speed, yaw_rate = payload  # type: ignore[misc]
            snap = snap._replace(w_in=yaw_rate)
            return self._wheel_update(snap, speed), True
        if kind == _IMU:
            yaw_rate, accel = payload  # type: ignore[misc]
            return snap._replace(w_in=yaw_rate, a_in=accel), True
        if kind == _WHEEL:
            return self._wheel_update(snap, payload), True  # type: ignore[arg-type]
        if kind == _GNSS_INS:
            return self._fuse_ins(snap, payload, reset, first_time)  # type: ignore[arg-type]
        if kind == _POSE:
            return self._fuse_pose(snap, payload, first_time)  # type: ignore[arg-type]
        return self._fuse_position(snap, payload, reset, first_time)  # type: ignore[arg-type]

    # --- prediction ----------------------------------------------------------------------------
    def _propagate(self, snap: _Snap, t_us: int) -> _Snap:
        """Kinematic prediction to ``t_us`` (may be backwards, for a look into the past)."""
        dt = (t_us - snap.t_us) / US_PER_S
        if dt == 0.0:
            return snap
        s, f, q = motion(self.config, snap.s, snap.w_in, snap.a_in, dt)
        p = f @ snap.p @ f.T
        p[_DIAG] += q
        if snap.gnss_quality is not None:
            # The GNSS error is a Gauss-Markov process: it decorrelates, towards its datasheet sigma.
            fade = math.exp(-abs(dt) / ERROR_CORRELATION_S)
            p[7:9, :] *= fade
            p[:, 7:9] *= fade
            q_g = ACCURACY_FLOOR_M[snap.gnss_quality] ** 2 * (1.0 - fade * fade)
            p[7, 7] += q_g
            p[8, 8] += q_g
            s[7:9] *= fade
        return snap._replace(t_us=t_us, s=s, p=p)

    def _propagate_pose(self, snap: _Snap, t_us: int) -> tuple[np.ndarray, np.ndarray]:
        """The state and the (3, 3) pose block of the covariance at ``t_us``: what ``estimate`` needs.

        The block is ``F[:3] P F[:3]^T + Q[:3, :3]``, exactly the top-left block of ``_propagate``'s
        covariance, at a third of the cost of the whole product.
        """
        dt = (t_us - snap.t_us) / US_PER_S
        if dt == 0.0:
            return snap.s, snap.p[:3, :3]
        s, f, q = motion(self.config, snap.s, snap.w_in, snap.a_in, dt)
        top = f[:3]
        p3 = top @ snap.p @ top.T
        p3[_DIAG3] += q[:3]
        return s, p3

    # --- corrections ---------------------------------------------------------------------------
    def _wheel_update(self, snap: _Snap, speed_mps: float) -> _Snap:
        """Wheel speed = speed x (1 + scale error)."""
        v, k = float(snap.s[V]), float(snap.s[K])
        # H has two non-zeros (speed and scale): P H^T is two columns, no matrix product needed.
        p = snap.p
        ph = p[:, V] * (1.0 + k) + p[:, K] * v
        gain = ph / (ph[V] * (1.0 + k) + ph[K] * v + self._r_odom)
        new_p = p - np.outer(gain, ph)
        s = snap.s + gain * (speed_mps - v * (1.0 + k))
        return snap._replace(s=s, p=0.5 * (new_p + new_p.T))

    def _fuse_ins(self, snap: _Snap, fix: GnssInsFrame, reset: bool, first_time: bool) -> tuple[_Snap, bool]:
        sigma = floored_sigma_m(fix.pos_std_m, fix.quality)
        r = np.diag([sigma**2, sigma**2]) + self._timing_cov(snap)
        if not snap.initialised or not snap.yaw_known or reset:
            snap = self._set_position(snap, fix.x_m, fix.y_m, r, fix.yaw_rad, fix.yaw_std_rad**2, False)
            return self._fuse_speed_yaw(snap, fix), self._count_accepted(first_time)
        h = np.zeros((2, N_STATES))
        h[0, X] = h[1, Y] = 1.0
        innovation = np.array([fix.x_m - snap.s[X], fix.y_m - snap.s[Y]])
        used, snap = self._gated_update(snap, h, innovation, r, first_time)
        if used is None:
            pos = np.array([fix.x_m, fix.y_m])
            snap = self._set_position(snap, pos[0], pos[1], r, fix.yaw_rad, fix.yaw_std_rad**2, False)
            used = True
        if not used:
            return snap, False
        return self._fuse_speed_yaw(snap, fix), True

    def _fuse_speed_yaw(self, snap: _Snap, fix: GnssInsFrame) -> _Snap:
        h = np.zeros((2, N_STATES))
        h[0, YAW] = h[1, V] = 1.0
        innovation = np.array([wrap_angle_rad(fix.yaw_rad - snap.s[YAW]), fix.speed_mps - snap.s[V]])
        r = np.diag([fix.yaw_std_rad**2, self.config.gnss_speed_std_mps**2])
        s, p = kalman_update(snap.s, snap.p, h, innovation, r)
        s[YAW] = wrap_angle_rad(s[YAW])
        return snap._replace(s=s, p=p)

    def _fuse_position(self, snap: _Snap, fix: GnssFix, reset: bool, first_time: bool) -> tuple[_Snap, bool]:
        xx, xy, yy = white_covariance_m2(fix)
        r = np.array([[xx, xy], [xy, yy]]) + self._timing_cov(snap)
        if snap.gnss_quality is not fix.quality:
            snap = self._restart_gnss_error(snap, fix.quality)
        if not snap.initialised or not snap.yaw_known:
            return self._initialise_from_positions(snap, fix, r), self._count_accepted(first_time)
        lf, ll = self._lever
        yaw = float(snap.s[YAW])
        cs, sn = math.cos(yaw), math.sin(yaw)
        h = np.zeros((2, N_STATES))
        h[0, X] = h[1, Y] = 1.0
        h[0, YAW], h[1, YAW] = -sn * lf - cs * ll, cs * lf - sn * ll
        h[0, GE] = h[1, GN] = 1.0
        antenna = (snap.s[X] + cs * lf - sn * ll, snap.s[Y] + sn * lf + cs * ll)
        predicted = (antenna[0] + snap.s[GE], antenna[1] + snap.s[GN])
        innovation = np.array([fix.x_m - predicted[0], fix.y_m - predicted[1]])
        if reset:
            return self._reset_to_fix(snap, fix, r), True
        used, snap = self._gated_update(snap, h, innovation, r, first_time)
        if used is None:
            return self._reset_to_fix(snap, fix, r), True
        return snap, used

    def _gated_update(
        self, snap: _Snap, h: np.ndarray, innovation: np.ndarray, r: np.ndarray, first_time: bool
    ) -> tuple[bool | None, _Snap]:
        """Chi-square gate, then update. None: rejected, and the re-acquisition rule says reset."""
        s_cov = h @ snap.p @ h.T + r
        d2 = float(innovation @ np.linalg.solve(s_cov, innovation))
        if d2 <= self.config.gate_chi2:
            if first_time:
                self._reacquisition.clear()
                self.accepted_fixes += 1
            s, p = kalman_update(snap.s, snap.p, h, innovation, r)
            s[YAW] = wrap_angle_rad(s[YAW])
            return True, snap._replace(s=s, p=p)
        if not first_time:
            return False, snap
        self.rejected_fixes += 1
        self.gross_rejections += d2 > self.config.gross_chi2
        self.max_rejected_chi2 = max(self.max_rejected_chi2, d2)
        rejected = RejectedFix(snap.t_us, innovation, r, snap.p[:2, :2].copy())
        if self._reacquisition.reject(rejected, snap.p[:2, :2]):
            self._reset_on_arrival = True
            self.resets += 1
            self.accepted_fixes += 1
            return None, snap
        return False, snap

    def _count_accepted(self, first_time: bool) -> bool:
        if first_time:
            self.accepted_fixes += 1
            self._reacquisition.clear()
        return True

    def _fuse_pose(self, snap: _Snap, measurement: PoseMeasurement, first_time: bool) -> tuple[_Snap, bool]:
        if not (snap.initialised and snap.yaw_known):
            return snap, False
        lin = measurement.linearize(snap.s[:3].copy(), snap.p[:3, :3].copy())
        if lin is None:
            return snap, False
        innovation, h3, r = lin
        m = innovation.shape[0]
        h = np.zeros((m, N_STATES))
        h[:, :3] = h3
        s_cov = h @ snap.p @ h.T + r
        if float(innovation @ np.linalg.solve(s_cov, innovation)) > _pose_gate(m):
            self.rejected_pose_measurements += first_time
            return snap, False
        s, p = kalman_update(snap.s, snap.p, h, innovation, r)
        s[YAW] = wrap_angle_rad(s[YAW])
        return snap._replace(s=s, p=p), True

    # --- (re-)initialisation -------------------------------------------------------------------
    def _timing_cov(self, snap: _Snap) -> np.ndarray:
        """Along-track uncertainty of a fix from its epoch's timing uncertainty."""
        v = float(snap.s[V]) if snap.initialised else 0.0
        yaw = float(snap.s[YAW])
        d = np.array([math.cos(yaw), math.sin(yaw)])
        return (v * self.config.fix_timing_std_s) ** 2 * np.outer(d, d)

    def _restart_gnss_error(self, snap: _Snap, quality: GnssQuality) -> _Snap:
        """A new solution type is a new error process: zero mean, its datasheet sigma, uncorrelated."""
        s, p = snap.s.copy(), snap.p.copy()
        s[7:9] = 0.0
        p[7:9, :] = 0.0
        p[:, 7:9] = 0.0
        p[7, 7] = p[8, 8] = ACCURACY_FLOOR_M[quality] ** 2
        return snap._replace(s=s, p=p, gnss_quality=quality)

    def _set_position(
        self,
        snap: _Snap,
        x: float,
        y: float,
        r: np.ndarray,
        yaw: float | None,
        yaw_var: float | None,
        position_fix: bool = True,
    ) -> _Snap:
        """Position (and yaw) from a fix; speed, biases and scale (with covariance) kept.

        For a position-only fix the measured point is the position plus the GNSS error state: the
        error restarts at zero with its sigma, and the position takes that sigma on, anti-correlated.
        """
        s, p = snap.s.copy(), snap.p.copy()
        s[X], s[Y] = x, y
        rows = [X, Y] if yaw is None else [X, Y, YAW]
        p[rows, :] = 0.0
        p[:, rows] = 0.0
        p[:2, :2] = r
        if position_fix and snap.gnss_quality is not None:
            bias_var = ACCURACY_FLOOR_M[snap.gnss_quality] ** 2
            s[7:9] = 0.0
            p[7:9, :] = 0.0
            p[:, 7:9] = 0.0
            eye = np.eye(2)
            p[:2, :2] += bias_var * eye
            p[:2, 7:9] = p[7:9, :2] = -bias_var * eye
            p[7:9, 7:9] = bias_var * eye
        if yaw is not None and yaw_var is not None:
            s[YAW] = wrap_angle_rad(yaw)
            p[YAW, YAW] = yaw_var
        return snap._replace(initialised=True, yaw_known=snap.yaw_known or yaw is not None, s=s, p=p)

    def _reset_to_fix(self, snap: _Snap, fix: GnssFix, r: np.ndarray) -> _Snap:
        """Re-acquisition: the base from the antenna fix with the filter's yaw; yaw doubt enters r."""
        lf, ll = self._lever
        yaw = float(snap.s[YAW])
        cs, sn = math.cos(yaw), math.sin(yaw)
        x = fix.x_m - (cs * lf - sn * ll)
        y = fix.y_m - (sn * lf + cs * ll)
        yaw_term = self._lever_sq * float(snap.p[YAW, YAW]) * np.eye(2)
        return self._set_position(snap, x, y, r + yaw_term, None, None)

    def _initialise_from_positions(self, snap: _Snap, fix: GnssFix, r: np.ndarray) -> _Snap:
        """Position from each fix until two fixes far enough apart give the heading (their course)."""
        loose = r + self._lever_sq * np.eye(2)  # the antenna may be anywhere on the lever-arm circle
        anchor = snap.anchor
        yaw_rel = float(snap.s[YAW])
        if anchor is None:
            snap = self._set_position(snap, fix.x_m, fix.y_m, loose, None, None)
            return snap._replace(anchor=(fix.x_m, fix.y_m, yaw_rel))
        dx, dy = fix.x_m - anchor[0], fix.y_m - anchor[1]
        dist = math.hypot(dx, dy)
        if dist < self.config.heading_init_distance_m:
            return self._set_position(snap, fix.x_m, fix.y_m, loose, None, None)
        # The course is the heading half-way (constant turn rate); the gyro gives the rest of the turn.
        turn = wrap_angle_rad(yaw_rel - anchor[2])
        course = math.atan2(dy, dx) + (math.pi if snap.s[V] < 0 else 0.0)
        yaw = wrap_angle_rad(course + 0.5 * turn)
        yaw_var = 2.0 * float(np.trace(loose)) / dist**2 + (0.5 * turn) ** 2
        lf, ll = self._lever
        cs, sn = math.cos(yaw), math.sin(yaw)
        r_base = r + self._lever_sq * yaw_var * np.eye(2)
        base_x, base_y = fix.x_m - (cs * lf - sn * ll), fix.y_m - (sn * lf + cs * ll)
        snap = self._set_position(snap, base_x, base_y, r_base, yaw, yaw_var)
        return snap._replace(anchor=None)


@functools.lru_cache(maxsize=64)
def _pose_gate(dof: int) -> float:
    """The 0.999 chi-square quantile of ``dof`` degrees of freedom (SciPy's ppf costs about a
    millisecond; a landmark frame's dimension repeats)."""
    return float(chi2.ppf(0.999, dof))


def _check_inputs(where: str, stamp: Stamp, **values: float) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise MessageError(f"{where}: expected a finite {name}, got {value}")
    if stamp < 0:
        raise MessageError(f"{where}: expected a non-negative stamp, got {stamp}")
