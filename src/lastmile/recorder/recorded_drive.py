"""A recorded real drive: GNSS fixes, IMU and wheel-speed samples on one clock, in a local ENU frame."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pyproj import Transformer

from lastmile.core.errors import LastmileError
from lastmile.core.gnss_messages import GnssFix, GnssQuality
from lastmile.core.stamp import Stamp


class DriveFormatError(LastmileError):
    """A recording is missing, malformed or lacks what is needed; names the file, line and column."""


@dataclass(frozen=True, slots=True)
class GeoFix:
    """One GNSS solution as read: absolute UTC time, WGS84 position, ENU covariance.

    Attributes:
        utc_us: UTC time of the epoch, µs since 1970-01-01.
        lat_deg, lon_deg, height_m: WGS84 latitude, longitude, ellipsoidal (or MSL) height.
        var_e_m2, var_en_m2, var_n_m2: horizontal covariance in east/north, m^2.
        quality: solution type.
    """

    utc_us: int
    lat_deg: float
    lon_deg: float
    height_m: float
    var_e_m2: float
    var_en_m2: float
    var_n_m2: float
    quality: GnssQuality


@dataclass(frozen=True, slots=True)
class ImuSamples:
    """IMU samples in the vehicle frame.

    Attributes:
        utc_us: (N,) int64, UTC µs, increasing.
        yaw_rate_radps: (N,) float64, about the up axis, counter-clockwise positive.
        accel_x_mps2: (N,) float64, specific force along the vehicle's forward axis; NaN when the
            recording has no usable longitudinal acceleration.
    """

    utc_us: np.ndarray
    yaw_rate_radps: np.ndarray
    accel_x_mps2: np.ndarray


@dataclass(frozen=True, slots=True)
class WheelSamples:
    """Wheel-odometry speeds: ``utc_us`` (M,) int64 and ``speed_mps`` (M,) float64, forward positive."""

    utc_us: np.ndarray
    speed_mps: np.ndarray


@dataclass(frozen=True, slots=True, kw_only=True)
class RecordedDrive:
    """A drive on the drive's own clock (stamp 0 = first sample of any stream) in a local ENU frame.

    Attributes:
        origin_lat_deg, origin_lon_deg, origin_height_m: the local frame's origin (the first fix).
        start_utc_us: UTC time of stamp 0, µs.
        fixes: GNSS fixes of the antenna, x east / y north in m, in time order.
        imu_us: (N,) int64 stamps; imu_yaw_rate_radps (N,); imu_accel_x_mps2 (N,) (NaN: none).
        wheel_us: (M,) int64 stamps; wheel_speed_mps (M,).
        sources: what was read from where, for the report.
    """

    origin_lat_deg: float
    origin_lon_deg: float
    origin_height_m: float
    start_utc_us: int
    fixes: tuple[GnssFix, ...]
    imu_us: np.ndarray
    imu_yaw_rate_radps: np.ndarray
    imu_accel_x_mps2: np.ndarray
    wheel_us: np.ndarray
    wheel_speed_mps: np.ndarray
    sources: tuple[str, ...] = field(default_factory=tuple)

    @property
    def has_accelerometer(self) -> bool:
        return bool(self.imu_us.size) and bool(np.isfinite(self.imu_accel_x_mps2).all())

    @property
    def duration_s(self) -> float:
        ends = [self.fixes[-1].stamp if self.fixes else 0]
        ends += [int(a[-1]) for a in (self.imu_us, self.wheel_us) if a.size]
        return max(ends) / 1e6


def enu_transformer(lat_deg: float, lon_deg: float, height_m: float) -> Transformer:
    """pyproj pipeline WGS84 (lon, lat, h in degrees and metres) -> local east, north, up at the origin."""
    return Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        "+step +proj=cart +ellps=WGS84 "
        f"+step +proj=topocentric +ellps=WGS84 +lat_0={lat_deg!r} +lon_0={lon_deg!r} +h_0={height_m!r}"
    )


def assemble_drive(
    fixes: list[GeoFix],
    imu: ImuSamples | None,
    wheel: WheelSamples | None,
    sources: tuple[str, ...],
) -> RecordedDrive:
    """Project the fixes to ENU at the first one and put every stream on the drive's clock.

    Raises:
        DriveFormatError: no fixes, no IMU or wheel speed, or streams that do not overlap in time.
    """
    if not fixes:
        raise DriveFormatError(f"{', '.join(sources)}: expected GNSS fixes, found none")
    if imu is None and wheel is None:
        raise DriveFormatError(
            f"{', '.join(sources)}: expected an IMU (yaw rate) or wheel-speed stream, found neither"
        )
    fixes = sorted(fixes, key=lambda f: f.utc_us)
    streams = [np.array([f.utc_us for f in fixes], dtype=np.int64)]
    streams += [s.utc_us for s in (imu, wheel) if s is not None and s.utc_us.size]
    start = min(int(s[0]) for s in streams)
    end_first = min(int(s[-1]) for s in streams)
    start_last = max(int(s[0]) for s in streams)
    if start_last >= end_first:
        raise DriveFormatError(
            f"{', '.join(sources)}: expected GNSS and IMU/wheel streams overlapping in time (UTC), got "
            f"spans starting {start_last / 1e6:.3f} s and ending {end_first / 1e6:.3f} s (GPST vs UTC?)"
        )
    origin = fixes[0]
    to_enu = enu_transformer(origin.lat_deg, origin.lon_deg, origin.height_m)
    lon = np.array([f.lon_deg for f in fixes])
    lat = np.array([f.lat_deg for f in fixes])
    h = np.array([f.height_m for f in fixes])
    east, north, _ = to_enu.transform(lon, lat, h)
    local = tuple(
        GnssFix(
            stamp=Stamp(f.utc_us - start),
            x_m=float(e),
            y_m=float(n),
            var_xx_m2=f.var_e_m2,
            var_xy_m2=f.var_en_m2,
            var_yy_m2=f.var_n_m2,
            quality=f.quality,
        )
        for f, e, n in zip(fixes, east, north, strict=True)
    )
    empty_i, empty_f = np.zeros(0, dtype=np.int64), np.zeros(0)
    return RecordedDrive(
        origin_lat_deg=origin.lat_deg,
        origin_lon_deg=origin.lon_deg,
        origin_height_m=origin.height_m,
        start_utc_us=start,
        fixes=local,
        imu_us=_ro(imu.utc_us - start if imu else empty_i),
        imu_yaw_rate_radps=_ro(imu.yaw_rate_radps if imu else empty_f),
        imu_accel_x_mps2=_ro(imu.accel_x_mps2 if imu else empty_f),
        wheel_us=_ro(wheel.utc_us - start if wheel else empty_i),
        wheel_speed_mps=_ro(wheel.speed_mps if wheel else empty_f),
        sources=sources,
    )


def _ro(values: np.ndarray) -> np.ndarray:
    arr = np.array(values, copy=True)
    arr.setflags(write=False)
    return arr


def check_finite(where: str, name: str, value: float) -> float:
    """Return ``value`` or raise DriveFormatError naming where it came from."""
    if not math.isfinite(value):
        raise DriveFormatError(f"{where} ({name}): expected a finite number, got {value}")
    return value
