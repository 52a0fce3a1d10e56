"""Parameters of the pose EKF, each from a datasheet, a standard or vehicle dynamics, never fitted."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from lastmile.core.errors import ConfigError

_DEG = math.pi / 180.0
_G_MPS2 = 9.80665


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseEkfConfig:
    """Sensor error model, gating, re-acquisition, integrity and history of :class:`PoseEkf`.

    The IMU figures are those of an industrial MEMS IMU (Analog Devices ADIS16470 datasheet, rev. C:
    rate noise density 0.008 deg/s/sqrt(Hz), in-run bias stability 8 deg/h, velocity random walk
    0.037 m/s/sqrt(h)); the vehicle figures come from vehicle dynamics and road design (sources on each
    field). A datasheet noise density is the floor; what dominates on a vehicle are the correlated
    errors (scale factors, road grade, body pitch, side slip), each modelled below with the time over
    which it stays correlated, so that the covariance grows as the real error does in an outage.

    Attributes:
        gyro_noise_radps: gyro white noise density, rad/s per sqrt(Hz) (ADIS16470: 0.008 deg/s/sqrt(Hz)).
        gyro_scale_error: prior one-sigma gyro scale-factor error, relative (industrial MEMS: 1 %). A
            state: over a turn it is a heading error proportional to the angle turned, the same
            sign at every turn the same way (a loop accumulates it), learnt in turns while GNSS is
            available.
        turn_correlation_s: how long a turn (and the slip and pitch errors it excites) lasts, s.
        yaw_rate_bias_std_radps: prior one-sigma gyro bias at start-up, rad/s (0.3 deg/s: MEMS turn-on
            bias over temperature).
        yaw_rate_bias_walk_radps: gyro bias random walk, rad/s per sqrt(s): twice the ADIS16470's
            in-run bias stability (8 deg/h) per sqrt(100 s), the second half for the bias's
            temperature coefficient as a cabin warms by a few degrees an hour.
        accel_noise_mps2: accelerometer white noise density, m/s^2 per sqrt(Hz) (ADIS16470 velocity
            random walk 0.037 m/s/sqrt(h) = 6.2e-4), raised tenfold for the vibration of a running
            vehicle body.
        pitch_gradient: body pitch per longitudinal acceleration, rad per (m/s^2) / g: gravity leaks
            into the longitudinal accelerometer as g x pitch (passenger cars pitch 1-2 deg per g,
            Gillespie, Fundamentals of Vehicle Dynamics, ch. 5: 2 deg per g).
        road_grade_std: road grade, one sigma (8.33 % is the steepest ramp the ADA standard allows;
            half of it), which the accelerometer reads as g x grade: a Gauss-Markov bias in distance.
        road_grade_length_m: distance over which the grade decorrelates (a vertical curve), m.
        speed_walk_mps2: when no accelerometer is fed, the speed is a random walk of this density,
            m/s^2 per sqrt(Hz): a shuttle's largest acceleration (Snow Lion, Table 2: -1.83 m/s^2)
            reached within a second.
        odom_speed_std_mps: wheel-speed noise (encoder quantisation, one sigma), m/s.
        odom_scale_std: prior one-sigma wheel-odometry scale error (rolling radius changes 1-3 % with
            tyre pressure, load and wear), relative; estimated as a state while GNSS is available.
        odom_scale_walk: random walk of that scale error, per sqrt(s) (tyre warm-up over minutes).
        side_slip_ratio: unmodelled sideways and along-track motion per speed (tyre slip angle of
            about 0.6 deg at the lateral accelerations a shuttle uses), relative, correlated over
            ``turn_correlation_s``.
        pos_noise_mps: floor of unmodelled motion at any speed (body roll moving the antenna,
            suspension), m/s per sqrt(Hz).
        gnss_speed_std_mps: noise of the INS speed in a :class:`GnssInsFrame`, m/s.
        antenna_lever_arm_m: GNSS antenna position in the base (rear axle) frame, (forward, left), m.
            Applies to position-only fixes (:class:`GnssFix`); an INS frame already reports the base.
        zero_slip_offset_m: distance ahead of the rear axle of the point whose velocity lies along the
            heading, m: 0 for front steer, half the wheelbase for opposite-phase all-wheel steer.
        fix_timing_std_s: uncertainty of a fix's epoch relative to the IMU clock, s (a receiver's PPS
            aligns them to microseconds; a logged NMEA time has 10 ms resolution).
        gate_chi2: 2-dof chi-square gate of a fix's position innovation (0.999 quantile: 13.8).
        gross_chi2: a rejected fix beyond this (20 sigma) is counted as gross as well.
        reacquire_window_s: rejected fixes spanning at least this long, all consistent with one
            offset, make the filter (not the receiver) the one presumed wrong, s.
        reacquire_min_fixes: and at least this many of them.
        reacquire_chi2_quantile: consistency test on the rejected fixes' innovations about their mean,
            each weighted by the fix's own reported covariance plus the filter's relative drift over
            the window; the chi-square quantile (0.999) of 2(n-1) dof it must stay below.
        max_pos_std_m: the estimate is invalid while its position sigma (largest axis) exceeds this, m.
        heading_init_distance_m: with position-only fixes the heading is initialised from the course
            between two fixes this far apart, m.
        history_s: how far back a late input is inserted at its own stamp, s.
    """

    gyro_noise_radps: float = 0.008 * _DEG
    gyro_scale_error: float = 0.01
    turn_correlation_s: float = 5.0
    yaw_rate_bias_std_radps: float = 0.3 * _DEG
    yaw_rate_bias_walk_radps: float = 2.0 * 8.0 * _DEG / 3600.0 / 10.0
    accel_noise_mps2: float = 10.0 * 0.037 / 60.0
    pitch_gradient: float = 2.0 * _DEG
    road_grade_std: float = 0.0833 / 2.0
    road_grade_length_m: float = 30.0
    speed_walk_mps2: float = 2.0
    odom_speed_std_mps: float = 0.05
    odom_scale_std: float = 0.02
    odom_scale_walk: float = 1e-4
    side_slip_ratio: float = 0.01
    pos_noise_mps: float = 0.01
    gnss_speed_std_mps: float = 0.1
    antenna_lever_arm_m: tuple[float, float] = (0.0, 0.0)
    zero_slip_offset_m: float = 1.45
    fix_timing_std_s: float = 0.01
    gate_chi2: float = 13.8
    gross_chi2: float = 400.0
    reacquire_window_s: float = 1.0
    reacquire_min_fixes: int = 3
    reacquire_chi2_quantile: float = 0.999
    max_pos_std_m: float = 1.0
    heading_init_distance_m: float = 5.0
    history_s: float = 1.0

    def __post_init__(self) -> None:
        positive = (
            "gyro_noise_radps",
            "turn_correlation_s",
            "yaw_rate_bias_std_radps",
            "accel_noise_mps2",
            "road_grade_length_m",
            "speed_walk_mps2",
            "odom_speed_std_mps",
            "pos_noise_mps",
            "gnss_speed_std_mps",
            "gate_chi2",
            "gross_chi2",
            "reacquire_window_s",
            "max_pos_std_m",
            "heading_init_distance_m",
            "history_s",
        )
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value > 0 and math.isfinite(value)):
                raise ConfigError(f"PoseEkfConfig.{name}: expected a positive number, got {value!r}")
        non_negative = (
            "gyro_scale_error",
            "yaw_rate_bias_walk_radps",
            "pitch_gradient",
            "road_grade_std",
            "odom_scale_std",
            "odom_scale_walk",
            "side_slip_ratio",
            "fix_timing_std_s",
        )
        for name in non_negative:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value >= 0 and math.isfinite(value)):
                raise ConfigError(f"PoseEkfConfig.{name}: expected a number >= 0, got {value!r}")
        lever = self.antenna_lever_arm_m
        if len(lever) != 2 or not all(math.isfinite(v) for v in (*lever, self.zero_slip_offset_m)):
            raise ConfigError(
                "PoseEkfConfig: expected a finite (forward, left) antenna_lever_arm_m and "
                f"zero_slip_offset_m, got {lever!r} and {self.zero_slip_offset_m!r}"
            )
        if self.gross_chi2 <= self.gate_chi2:
            raise ConfigError(
                f"PoseEkfConfig.gross_chi2: expected above gate_chi2 ({self.gate_chi2}), "
                f"got {self.gross_chi2}"
            )
        if self.reacquire_min_fixes < 2:
            raise ConfigError(
                f"PoseEkfConfig.reacquire_min_fixes: expected at least 2, got {self.reacquire_min_fixes}"
            )
        if not 0.5 < self.reacquire_chi2_quantile < 1.0:
            raise ConfigError(
                "PoseEkfConfig.reacquire_chi2_quantile: expected in (0.5, 1), "
                f"got {self.reacquire_chi2_quantile}"
            )

    def with_imu(self, name: str) -> PoseEkfConfig:
        """This configuration with the IMU error model of a named grade (``IMU_PROFILES``).

        Raises:
            ConfigError: an unknown name.
        """
        profile = IMU_PROFILES.get(name)
        if profile is None:
            raise ConfigError(f"IMU grade: expected one of {', '.join(IMU_PROFILES)}, got {name!r}")
        return dataclasses.replace(
            self,
            gyro_noise_radps=profile.gyro_noise_radps,
            gyro_scale_error=profile.gyro_scale_error,
            yaw_rate_bias_std_radps=profile.yaw_rate_bias_std_radps,
            yaw_rate_bias_walk_radps=profile.yaw_rate_bias_walk_radps,
            accel_noise_mps2=profile.accel_noise_mps2,
        )

    @property
    def grade_accel_std_mps2(self) -> float:
        """One sigma of the accelerometer reading caused by road grade, m/s^2."""
        return _G_MPS2 * self.road_grade_std


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuProfile:
    """An IMU grade's error model (the fields of :class:`PoseEkfConfig` of the same names)."""

    gyro_noise_radps: float
    gyro_scale_error: float
    yaw_rate_bias_std_radps: float
    yaw_rate_bias_walk_radps: float
    accel_noise_mps2: float


_DEFAULT = PoseEkfConfig()
_VIBRATION = 10.0  # a running vehicle body's vibration over a bench datasheet's accelerometer noise

IMU_PROFILES: dict[str, ImuProfile] = {
    # Analog Devices ADIS16470 (rev. C): the defaults of PoseEkfConfig.
    "industrial_mems": ImuProfile(
        gyro_noise_radps=_DEFAULT.gyro_noise_radps,
        gyro_scale_error=_DEFAULT.gyro_scale_error,
        yaw_rate_bias_std_radps=_DEFAULT.yaw_rate_bias_std_radps,
        yaw_rate_bias_walk_radps=_DEFAULT.yaw_rate_bias_walk_radps,
        accel_noise_mps2=_DEFAULT.accel_noise_mps2,
    ),
    # InvenSense MPU-6000/6050 class (PS-MPU-6000A-00 rev. 3.4): rate noise 0.005 deg/s/sqrt(Hz),
    # sensitivity tolerance +-3 %, zero-rate output drift +-20 deg/s over 125 degC (0.16 deg/s per degC:
    # a cabin warming by 1 degC in 10 min moves the bias by 0.16 deg/s, a random walk of
    # 0.0065 deg/s per sqrt(s)), accelerometer noise 400 ug/sqrt(Hz). The start-up bias prior is
    # 1 deg/s: drivers remove the datasheet's +-20 deg/s untrimmed offset at start-up.
    "consumer_mems": ImuProfile(
        gyro_noise_radps=0.005 * _DEG,
        gyro_scale_error=0.03,
        yaw_rate_bias_std_radps=1.0 * _DEG,
        yaw_rate_bias_walk_radps=0.16 * _DEG / math.sqrt(600.0),
        accel_noise_mps2=_VIBRATION * 400e-6 * _G_MPS2,
    ),
}
"""IMU grades by name, from their datasheets."""
