"""The `ekf` localization mode (the default): odometry and IMU yaw rate drive a pose EKF, RTK corrects it.

State: rear-axle x_m, y_m, yaw_rad in the map frame, speed_mps and the IMU's yaw-rate bias. All
algebra is written out on plain floats (a 5x5 symmetric covariance is 15 numbers): the filter runs
at 50-100 Hz inside a loop that must be much faster than real time, where even tiny NumPy calls cost
more than the arithmetic. A short history of inputs and posteriors lets late GNSS fixes (their
latency exceeds the odometry's) be inserted at their own stamp and the newer inputs re-applied.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.gnss_messages import floored_sigma_m
from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.stamp import US_PER_S, Stamp
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.localization.position_source import AbsoluteUpdates


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryEkfConfig:
    """Noise, gating, integrity and history parameters.

    Attributes:
        odom_speed_std_mps: wheel-odometry speed noise (one sigma), m/s.
        gnss_speed_std_mps: noise of the INS speed fused with each accepted fix (one sigma), m/s.
        accel_noise_mps2: unmodelled acceleration between inputs (white, density), m/s^2 per sqrt(Hz).
        yaw_rate_noise_radps: IMU yaw-rate noise (white, density), rad/s per sqrt(Hz).
        pos_noise_mps: unmodelled motion of the rear axle (tyre slip, bumps; white, density), m/s
            per sqrt(Hz).
        yaw_rate_bias_std_radps: prior one-sigma IMU yaw-rate bias, rad/s.
        yaw_rate_bias_walk_radps: random walk of that bias: its sigma after one second, rad/s.
        zero_slip_offset_m: distance ahead of the rear axle of the point whose velocity lies along the
            heading, m: 0 for front-steer vehicles, half the wheelbase for opposite-phase all-wheel
            steer, where the rear axle slides sideways at yaw rate times this (0.18 m/s on a 40 m
            radius at 5 m/s: a metre of drift in a 5 s GNSS outage if ignored). The default is half
            the default shuttle's 2.9 m wheelbase (``VehicleGeometry``, all-wheel steer).
        gate_chi2: chi-square bound (2 dof, position) beyond which a fix is rejected as an outlier;
            13.8 is the 0.999 quantile.
        gross_chi2: a rejected fix beyond this bound (400: 20 sigma) is counted as gross as well: no
            noise or model error of a healthy run reaches it, so one such fix is already a
            receiver fault (multipath, a map misalignment), not bad luck.
        reset_after_rejections: this many consecutive rejected fixes mean the filter, not the
            receiver, is wrong: the next fix re-initialises it, provided the rejected fixes agree
            with each other (a drifted filter sees one consistent offset; multipath jumps around).
        reset_consistency_m: how far the rejected fixes' innovations may spread about their mean
            for a reset, m. RTK noise is centimetres and a drifting filter's offset hardly changes in
            3 s, while multipath jumping a few metres in a new direction every second can line up two
            jumps within a metre by chance: hence 3 s of rejections and 0.3 m.
        max_pos_std_m: the estimate is marked invalid while its position sigma (largest axis)
            exceeds this, m.
        history_s: how far back a late input is inserted at its own stamp, s; older ones are dropped.
    """

    odom_speed_std_mps: float = 0.05
    gnss_speed_std_mps: float = 0.1
    accel_noise_mps2: float = 1.0
    yaw_rate_noise_radps: float = 0.003
    pos_noise_mps: float = 0.05
    yaw_rate_bias_std_radps: float = 0.005
    yaw_rate_bias_walk_radps: float = 1e-4
    zero_slip_offset_m: float = 1.45
    gate_chi2: float = 13.8
    gross_chi2: float = 400.0
    reset_after_rejections: int = 30
    reset_consistency_m: float = 0.3
    max_pos_std_m: float = 1.0
    history_s: float = 1.0

    def __post_init__(self) -> None:
        for name in (
            "odom_speed_std_mps",
            "gnss_speed_std_mps",
            "accel_noise_mps2",
            "yaw_rate_noise_radps",
            "pos_noise_mps",
            "yaw_rate_bias_std_radps",
            "gate_chi2",
            "gross_chi2",
            "max_pos_std_m",
            "history_s",
        ):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"OdometryEkfConfig.{name}: expected a positive number, got {value}")
        if not (self.yaw_rate_bias_walk_radps >= 0 and math.isfinite(self.zero_slip_offset_m)):
            raise ConfigError(
                "OdometryEkfConfig: expected yaw_rate_bias_walk_radps >= 0 and a finite zero_slip_offset_m, "
                f"got {self.yaw_rate_bias_walk_radps} and {self.zero_slip_offset_m}"
            )
        if self.gross_chi2 <= self.gate_chi2:
            raise ConfigError(
                f"OdometryEkfConfig.gross_chi2: expected above gate_chi2 ({self.gate_chi2}), "
                f"got {self.gross_chi2}"
            )
        if self.reset_after_rejections < 1:
            raise ConfigError(
                "OdometryEkfConfig.reset_after_rejections: expected at least 1, "
                f"got {self.reset_after_rejections}"
            )


# The 5x5 covariance is packed as its upper triangle, row by row:
# 00 01 02 03 04 11 12 13 14 22 23 24 33 34 44.
_PAIRS = tuple((i, j) for i in range(5) for j in range(i, 5))
_PACKED = tuple(tuple(_PAIRS.index((min(i, j), max(i, j))) for j in range(5)) for i in range(5))
_X, _Y, _YAW, _V, _BIAS = range(5)
_UNKNOWN_VAR = 1e6  # prior variance of position before the first fix (m^2) and of speed ((m/s)^2)

# A snapshot is the posterior after one input: (t_us, initialised, held inputs, state, packed_cov);
# the held inputs are (yaw_rate_radps, zero_slip_offset_m), the motion inputs between two inputs;
# t_us < 0 before the first input. Events are (t_us, kind, payload, snapshot).
_Held = tuple[float, float]
_Snapshot = tuple[int, bool, _Held, tuple[float, ...], tuple[float, ...]]
# (speed_mps, yaw_rate_radps, zero_slip_offset_m or NaN to keep the held one) from odometry and IMU.
_Payload = tuple[float, float, float] | GnssInsFrame
_ODOM, _GNSS, _GNSS_RESET = 0, 1, 2


STRAIGHT_STEER = 1e-3
"""Below this difference of the wheel angles' tangents the body hardly turns from steering: the
zero-slip point is then left as it was (it only matters times the yaw rate)."""


def zero_slip_offset_m(wheelbase_m: float, steer_front_rad: float, steer_rear_rad: float) -> float | None:
    """Where the body has no sideways velocity, m ahead of the rear axle, from the wheel angles.

    Kinematic (no tyre slip) body with front and rear wheels at angles df and dr: the sideways
    velocity grows linearly along the body, from v tan(dr) at the rear axle to v tan(df) at the front
    one, so it vanishes at ``-tan(dr) L / (tan(df) - tan(dr))``: the rear axle with the rear wheels
    straight, mid-wheelbase when they steer opposite to the front. An all-wheel-steer shuttle that
    keeps its rear wheels straight (at a curb) moves its zero-slip point, and a filter that assumes
    mid-wheelbase then slides the rear axle outwards at yaw rate x L/2 (0.36 m/s in a 0.25 rad/s
    pull-over at 3.4 m/s: its GNSS fixes rejected within a second). None when the wheels are near
    parallel (no turn from steering).
    """
    tan_f, tan_r = math.tan(steer_front_rad), math.tan(steer_rear_rad)
    if abs(tan_f - tan_r) < STRAIGHT_STEER:
        return None
    return -tan_r * wheelbase_m / (tan_f - tan_r)


class OdometryEkf:
    """Extended Kalman filter over (x, y, yaw, speed, yaw-rate bias) of the rear axle.

    Inputs may arrive slightly out of order: one older than the newest input is inserted at its
    stamp within ``history_s`` and every newer input is re-applied, so the result equals in-order
    processing. ``estimate`` may also be asked for a past stamp (a radar frame's capture time).
    """

    def __init__(self, config: OdometryEkfConfig | None = None) -> None:
        self.config = c = config or OdometryEkfConfig()
        self.absolute = AbsoluteUpdates()
        """When a fix was last accepted (the estimate's ``source``: GNSS or dead reckoning)."""
        self.rejected_fixes = 0
        """Fixes rejected by the chi-square gate (each counted once, when it arrives)."""
        self.gross_rejections = 0
        """Of those, the fixes beyond ``gross_chi2``."""
        self.max_rejected_chi2 = 0.0
        """The largest squared Mahalanobis distance of a rejected fix so far (for tuning reports)."""
        self.dropped_inputs = 0
        """Inputs older than the history, dropped."""
        self.resets = 0
        """Re-initialisations after ``reset_after_rejections`` consecutive rejections."""
        self._consecutive_rejections = 0
        self._rejected_innovations: deque[tuple[float, float]] = deque(
            maxlen=self.config.reset_after_rejections
        )
        self._reset_on_arrival = False
        prior = [0.0] * 15
        prior[_PACKED[_X][_X]] = prior[_PACKED[_Y][_Y]] = _UNKNOWN_VAR
        prior[_PACKED[_YAW][_YAW]] = math.pi**2
        prior[_PACKED[_V][_V]] = _UNKNOWN_VAR
        prior[_PACKED[_BIAS][_BIAS]] = c.yaw_rate_bias_std_radps**2
        self._latest: _Snapshot = (
            -1,
            False,
            (0.0, c.zero_slip_offset_m),
            (0.0, 0.0, 0.0, 0.0, 0.0),
            tuple(prior),
        )
        self._events: list[tuple[int, int, _Payload, _Snapshot]] = []
        self._history_us = round(c.history_s * US_PER_S)
        self._q_pos = c.pos_noise_mps**2
        self._q_yaw = c.yaw_rate_noise_radps**2
        self._q_speed = c.accel_noise_mps2**2
        self._q_bias = c.yaw_rate_bias_walk_radps**2
        self._r_odom = c.odom_speed_std_mps**2
        self._r_gnss_speed = c.gnss_speed_std_mps**2

    @property
    def initialised(self) -> bool:
        """Whether a GNSS fix has set the pose."""
        return self._latest[1]

    @property
    def yaw_rate_bias_radps(self) -> float:
        """Current estimate of the IMU yaw-rate bias (subtracted from every IMU reading)."""
        return self._latest[3][_BIAS]

    def predict(
        self,
        stamp: Stamp,
        speed_mps: float,
        yaw_rate_radps: float,
        zero_slip_offset_m: float | None = None,
    ) -> None:
        """Move the filter to ``stamp`` and take a new odometry speed and IMU yaw rate.

        The motion up to ``stamp`` uses the previous yaw rate and zero-slip point (held since the
        last call); the speed is a measurement of the speed state.

        Args:
            stamp: capture time of the odometry sample, µs.
            speed_mps: wheel-odometry speed of the rear axle (forward positive).
            yaw_rate_radps: latest IMU yaw rate (counter-clockwise positive), bias included.
            zero_slip_offset_m: where the body has no sideways velocity now, m ahead of the rear axle
                (:func:`zero_slip_offset_m` of the measured wheel angles); None keeps the held one
                (initially the configuration's).

        Raises:
            MessageError: a non-finite input or a negative stamp.
        """
        lever = math.nan if zero_slip_offset_m is None else zero_slip_offset_m
        if not (
            math.isfinite(speed_mps)
            and math.isfinite(yaw_rate_radps)
            and (zero_slip_offset_m is None or math.isfinite(lever))
        ):
            raise MessageError(
                "OdometryEkf.predict: expected finite speed_mps, yaw_rate_radps and zero_slip_offset_m, "
                f"got {speed_mps}, {yaw_rate_radps}, {zero_slip_offset_m}"
            )
        if stamp < 0:
            raise MessageError(f"OdometryEkf.predict: expected a non-negative stamp, got {stamp}")
        self._insert(int(stamp), _ODOM, (speed_mps, yaw_rate_radps, lever))

    def update_gnss(self, frame: GnssInsFrame) -> bool:
        """Correct with an RTK GNSS/INS fix (position, yaw and speed, with the frame's std devs).

        Returns:
            True if the fix was used; False when ``fix_ok`` is False, the chi-square gate rejected it
            (counted in ``rejected_fixes``) or it was older than the history (``dropped_inputs``).

        Raises:
            MessageError: a non-finite field, a non-positive std dev or a negative stamp.
        """
        frame.validate_for_fusion()
        if not frame.fix_ok:
            return False
        used = self._insert(int(frame.stamp), _GNSS, frame)
        if used:
            self.absolute.note(PositionSource.GNSS, int(frame.stamp))
        return used

    def estimate(self, stamp: Stamp) -> LocalizationEstimate:
        """The pose at ``stamp``, extrapolated from the newest posterior at or before it.

        Nothing is stored. A stamp older than the history is extrapolated backwards from its oldest
        posterior. ``valid`` is False before the first fix and while the position sigma exceeds
        ``max_pos_std_m``.
        """
        snap = self._latest
        events = self._events
        if events and stamp < snap[0]:
            k = len(events) - 1
            while k > 0 and events[k][0] > stamp:
                k -= 1
            snap = events[k][3]
        if snap[0] >= 0:
            snap = self._propagate(snap, int(stamp))
        _, initialised, (yaw_rate_in, _), s, p = snap
        a, b, d = p[0], p[1], p[5]
        pos_std = math.sqrt(0.5 * (a + d) + math.sqrt(0.25 * (a - d) ** 2 + b * b))
        return LocalizationEstimate(
            stamp=stamp,
            map_from_base=SE2(s[_X], s[_Y], s[_YAW]),
            speed_mps=s[_V],
            yaw_rate_radps=yaw_rate_in - s[_BIAS],
            pos_std_m=pos_std,
            yaw_std_rad=math.sqrt(p[9]),
            valid=initialised and pos_std <= self.config.max_pos_std_m,
            source=self.absolute.source_at(int(stamp)),
        )

    # --------------------------------------------------------------------------------------------
    def _insert(self, t_us: int, kind: int, payload: _Payload) -> bool:
        """Apply one input at its stamp, re-applying newer ones; returns whether it was used."""
        events = self._events
        if not events or t_us >= events[-1][0]:
            snap, used = self._apply(self._latest, t_us, kind, payload, first_time=True)
            events.append((t_us, self._kind_to_replay(kind), payload, snap))
            self._latest = snap
            cutoff = t_us - self._history_us
            if events[0][0] < cutoff:
                k = 0
                while events[k][0] < cutoff and k < len(events) - 1:
                    k += 1
                del events[:k]
            return used
        k = len(events)
        while k > 0 and events[k - 1][0] > t_us:
            k -= 1
        if k == 0:
            self.dropped_inputs += 1
            return False
        snap, used = self._apply(events[k - 1][3], t_us, kind, payload, first_time=True)
        events.insert(k, (t_us, self._kind_to_replay(kind), payload, snap))
        for j in range(k + 1, len(events)):
            tj, kj, pj, _ = events[j]
            snap, _ = self._apply(snap, tj, kj, pj, first_time=False)
            events[j] = (tj, kj, pj, snap)
        self._latest = snap
        return used

    def _kind_to_replay(self, kind: int) -> int:
        # A reset decided on arrival stays a reset on every replay (replays never count or decide).
        if self._reset_on_arrival:
            self._reset_on_arrival = False
            return _GNSS_RESET
        return kind

    def _apply(
        self, snap: _Snapshot, t_us: int, kind: int, payload: _Payload, first_time: bool
    ) -> tuple[_Snapshot, bool]:
        snap = self._propagate(snap, t_us)
        if isinstance(payload, GnssInsFrame):
            return self._fuse_fix(snap, payload, reset=kind == _GNSS_RESET, first_time=first_time)
        speed_mps, yaw_rate_radps, lever = payload
        held = (yaw_rate_radps, snap[2][1] if math.isnan(lever) else lever)
        s, p = self._scalar_update(snap[3], snap[4], _V, speed_mps - snap[3][_V], self._r_odom)
        return (t_us, snap[1], held, s, p), True

    def _propagate(self, snap: _Snapshot, t_us: int) -> _Snapshot:
        """Kinematic prediction to ``t_us`` (may be backwards for a look into the past)."""
        t0, initialised, held, s, p = snap
        if t0 < 0:
            return (t_us, initialised, held, s, p)
        dt = (t_us - t0) / US_PER_S
        if dt == 0.0:
            return snap
        x, y, yaw, v, bias = s
        p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44 = p
        w_in, lever = held
        w = w_in - bias
        # Midpoint heading: exact for constant speed and yaw rate up to second order.
        mid = yaw + 0.5 * w * dt
        c, sn = math.cos(mid), math.sin(mid)
        vx = v * c + w * lever * sn
        vy = v * sn - w * lever * c
        # Jacobian F = I + [[0,0,a,cx,e],[0,0,b,cy,g],[0,0,0,0,h],0,0].
        a, b = -vy * dt, vx * dt
        cx, cy = c * dt, sn * dt
        e = -0.5 * a * dt - lever * sn * dt
        g = -0.5 * b * dt + lever * c * dt
        h = -dt
        # M = F P (rows 0..2; rows 3 and 4 are unchanged), then F M^T, upper triangle only.
        m00 = p00 + a * p02 + cx * p03 + e * p04
        m01 = p01 + a * p12 + cx * p13 + e * p14
        m02 = p02 + a * p22 + cx * p23 + e * p24
        m03 = p03 + a * p23 + cx * p33 + e * p34
        m04 = p04 + a * p24 + cx * p34 + e * p44
        m11 = p11 + b * p12 + cy * p13 + g * p14
        m12 = p12 + b * p22 + cy * p23 + g * p24
        m13 = p13 + b * p23 + cy * p33 + g * p34
        m14 = p14 + b * p24 + cy * p34 + g * p44
        m22 = p22 + h * p24
        m24 = p24 + h * p44
        adt = abs(dt)
        q_pos = self._q_pos * adt
        return (
            t_us,
            initialised,
            held,
            (x + vx * dt, y + vy * dt, wrap_angle_rad(yaw + w * dt), v, bias),
            (
                m00 + a * m02 + cx * m03 + e * m04 + q_pos,
                m01 + b * m02 + cy * m03 + g * m04,
                m02 + h * m04,
                m03,
                m04,
                m11 + b * m12 + cy * m13 + g * m14 + q_pos,
                m12 + h * m14,
                m13,
                m14,
                m22 + h * m24 + self._q_yaw * adt,
                p23 + h * p34,
                m24,
                p33 + self._q_speed * adt,
                p34,
                p44 + self._q_bias * adt,
            ),
        )

    @staticmethod
    def _scalar_update(
        s: tuple[float, ...], p: tuple[float, ...], index: int, innovation: float, r: float
    ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Kalman update with one directly measured state component (H = e_index)."""
        col = [p[k] for k in _PACKED[index]]
        gain = [ci / (col[index] + r) for ci in col]
        new_s = tuple(si + gi * innovation for si, gi in zip(s, gain, strict=True))
        new_p = tuple(pk - gain[i] * col[j] for pk, (i, j) in zip(p, _PAIRS, strict=True))
        return new_s, new_p

    def _fuse_fix(
        self, snap: _Snapshot, fix: GnssInsFrame, reset: bool, first_time: bool
    ) -> tuple[_Snapshot, bool]:
        t_us, initialised, held, s, p = snap
        r_pos = floored_sigma_m(fix.pos_std_m, fix.quality) ** 2
        if not initialised or reset:
            return self._initialise(snap, fix), True
        dx, dy = fix.x_m - s[_X], fix.y_m - s[_Y]
        s00, s01, s11 = p[0] + r_pos, p[1], p[5] + r_pos
        d2 = (s11 * dx * dx - 2.0 * s01 * dx * dy + s00 * dy * dy) / (s00 * s11 - s01 * s01)
        if d2 > self.config.gate_chi2:
            if first_time:
                self.rejected_fixes += 1
                self.gross_rejections += d2 > self.config.gross_chi2
                self.max_rejected_chi2 = max(self.max_rejected_chi2, d2)
                self._consecutive_rejections += 1
                self._rejected_innovations.append((dx, dy))
                if (
                    self._consecutive_rejections >= self.config.reset_after_rejections
                    and self._innovations_agree()
                ):
                    # The filter has been wrong for a while (long drift, a bad reset): trust the fix.
                    self._consecutive_rejections = 0
                    self._reset_on_arrival = True
                    self.resets += 1
                    return self._initialise(snap, fix), True
            return snap, False
        if first_time:
            self._consecutive_rejections = 0
            self._rejected_innovations.clear()
        s, p = self._scalar_update(s, p, _X, dx, r_pos)
        s, p = self._scalar_update(s, p, _Y, fix.y_m - s[_Y], r_pos)
        s, p = self._scalar_update(s, p, _YAW, wrap_angle_rad(fix.yaw_rad - s[_YAW]), fix.yaw_std_rad**2)
        s, p = self._scalar_update(s, p, _V, fix.speed_mps - s[_V], self._r_gnss_speed)
        return (t_us, True, held, (s[0], s[1], wrap_angle_rad(s[2]), s[3], s[4]), p), True

    def _innovations_agree(self) -> bool:
        inn = self._rejected_innovations
        mx = sum(d[0] for d in inn) / len(inn)
        my = sum(d[1] for d in inn) / len(inn)
        spread = max(math.hypot(dx - mx, dy - my) for dx, dy in inn)
        return spread <= self.config.reset_consistency_m

    def _initialise(self, snap: _Snapshot, fix: GnssInsFrame) -> _Snapshot:
        """Pose from the fix; speed and bias (and their covariance) kept from the odometry so far."""
        t_us, _, held, s, p = snap
        r_pos = floored_sigma_m(fix.pos_std_m, fix.quality) ** 2
        new_p = list(p)
        for i in (_X, _Y, _YAW):
            for j in range(5):
                new_p[_PACKED[i][j]] = 0.0
        new_p[_PACKED[_X][_X]] = new_p[_PACKED[_Y][_Y]] = r_pos
        new_p[_PACKED[_YAW][_YAW]] = fix.yaw_std_rad**2
        state: tuple[float, ...] = (fix.x_m, fix.y_m, wrap_angle_rad(fix.yaw_rad), s[_V], s[_BIAS])
        state, packed = self._scalar_update(
            state, tuple(new_p), _V, fix.speed_mps - s[_V], self._r_gnss_speed
        )
        return (t_us, True, held, state, packed)
