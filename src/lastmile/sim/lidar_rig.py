"""The LiDAR rig: each unit's mounting and beams (``LidarSpec``), the default WATonoBus-style rig, rig
tables from config, and the shuttle's poses over a sweep (``EgoTrack``) that a sweep is cast along."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.arrays import frozen_array
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.vehicle import VehicleGeometry

# Velodyne VLP-32C beam elevations (deg): dense around the horizon where small objects are far.
VLP32C_ELEVATIONS_DEG = (
    -25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333, -3.0,
    -2.667, -2.333, -2.0, -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333, 0.667, 1.0, 1.333,
    1.667, 2.333, 3.333, 4.667, 7.0, 10.333, 15.0,
)  # fmt: skip
# A 16-channel blind-spot unit looks mostly down at the road beside the shuttle.
BLIND_SPOT_ELEVATIONS_DEG = tuple(float(e) for e in np.linspace(-40.0, 10.0, 16))


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarSpec:
    """One spinning LiDAR: mounting on the base frame (rear axle, x forward, z up from the road).

    The unit is mounted level (no roll or pitch); ``yaw_rad`` turns its x axis from the base's.

    Attributes:
        elevations_deg: beam elevations, any order; ring numbers count from the lowest beam.
        azimuth_res_deg: horizontal step between columns (360 / res columns per sweep).
        period_us: one revolution (100 ms at 10 Hz); the sweep's stamp is its first column.
        clockwise: spin direction seen from above (Velodyne and Robosense spin clockwise).
        start_azimuth_rad: sensor-frame azimuth of the first column (pi: the sweep starts behind).
        latency_us: from the end of the sweep to its delivery to the stack.
    """

    sensor_id: str
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    elevations_deg: tuple[float, ...]
    azimuth_res_deg: float = 0.2
    period_us: int = 100_000
    max_range_m: float = 100.0
    min_range_m: float = 0.5
    range_noise_std_m: float = 0.02
    clockwise: bool = True
    start_azimuth_rad: float = math.pi
    latency_us: int = 20_000

    def __post_init__(self) -> None:
        for name in ("x_m", "y_m", "z_m", "yaw_rad", "start_azimuth_rad"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ConfigError(
                    f"LidarSpec {self.sensor_id!r}.{name}: expected a finite number, got {value}"
                )
        for name in ("azimuth_res_deg", "max_range_m", "min_range_m", "range_noise_std_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(
                    f"LidarSpec {self.sensor_id!r}.{name}: expected a finite number >= 0, got {value}"
                )
        if not 0.01 <= self.azimuth_res_deg <= 5.0:
            raise ConfigError(
                f"LidarSpec {self.sensor_id!r}.azimuth_res_deg: expected 0.01..5 deg, "
                f"got {self.azimuth_res_deg}"
            )
        if self.period_us <= 0 or self.latency_us < 0:
            raise ConfigError(
                f"LidarSpec {self.sensor_id!r}: expected period_us > 0 and latency_us >= 0, got "
                f"{self.period_us}, {self.latency_us}"
            )
        if not self.min_range_m < self.max_range_m:
            raise ConfigError(
                f"LidarSpec {self.sensor_id!r}: expected min_range_m < max_range_m, got "
                f"{self.min_range_m} >= {self.max_range_m}"
            )
        els = self.elevations_deg
        if (
            not els
            or not all(math.isfinite(e) and -89.0 < e < 89.0 for e in els)
            or len(set(els)) != len(els)
        ):
            raise ConfigError(
                f"LidarSpec {self.sensor_id!r}.elevations_deg: expected distinct finite angles "
                f"in (-89, 89), got {els}"
            )

    @property
    def base_from_sensor(self) -> np.ndarray:
        """(4, 4) mounting transform (level unit: a yaw and a translation), the stack's calibration."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        T = np.eye(4)
        T[:2, :2] = ((c, -s), (s, c))
        T[:3, 3] = (self.x_m, self.y_m, self.z_m)
        return T

    @property
    def n_columns(self) -> int:
        return round(360.0 / self.azimuth_res_deg)

    @property
    def n_rays(self) -> int:
        return self.n_columns * len(self.elevations_deg)


def lidar_specs_from_config(rows: list[dict[str, object]]) -> tuple[LidarSpec, ...]:
    """LiDAR specs from config tables (as read from TOML), one per sensor.

    Raises:
        ConfigError: an unknown key, a missing one, or a value :class:`LidarSpec` refuses.
    """
    known = set(LidarSpec.__dataclass_fields__)
    out = []
    for i, row in enumerate(rows):
        unknown = sorted(set(row) - known)
        if unknown:
            raise ConfigError(f"lidar[{i}]: expected keys among {sorted(known)}, got unknown {unknown}")
        values = dict(row)
        if "elevations_deg" in values:
            values["elevations_deg"] = tuple(float(e) for e in values["elevations_deg"])  # type: ignore[attr-defined]
        try:
            out.append(LidarSpec(**values))  # type: ignore[arg-type]
        except TypeError as exc:
            raise ConfigError(f"lidar[{i}]: expected every LidarSpec field, got {exc}") from None
    return tuple(out)


def default_lidar_rig(geometry: VehicleGeometry) -> tuple[LidarSpec, ...]:
    """WATonoBus-style rig: a 32-channel unit on the front face, 16-channel blind-spot units each side.

    The front unit sits 1.9 m up on the nose (its rear half is blocked by the body, as on the
    vehicle); the side units sit 0.9 m up at mid-wheelbase facing outwards.
    """
    mid = geometry.wheelbase_m / 2.0
    side_y = geometry.width_m / 2.0 + 0.05
    return (
        LidarSpec(
            sensor_id="front",
            x_m=geometry.front_from_rear_axle_m + 0.05,
            y_m=0.0,
            z_m=1.9,
            yaw_rad=0.0,
            elevations_deg=VLP32C_ELEVATIONS_DEG,
            azimuth_res_deg=0.2,
            max_range_m=100.0,
        ),
        LidarSpec(
            sensor_id="left",
            x_m=mid,
            y_m=side_y,
            z_m=0.9,
            yaw_rad=math.pi / 2.0,
            elevations_deg=BLIND_SPOT_ELEVATIONS_DEG,
            azimuth_res_deg=0.4,
            max_range_m=40.0,
        ),
        LidarSpec(
            sensor_id="right",
            x_m=mid,
            y_m=-side_y,
            z_m=0.9,
            yaw_rad=-math.pi / 2.0,
            elevations_deg=BLIND_SPOT_ELEVATIONS_DEG,
            azimuth_res_deg=0.4,
            max_range_m=40.0,
        ),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class EgoTrack:
    """Poses of the base (rear axle) in the map frame over a sweep; linearly interpolated.

    Attributes:
        t_us: (T,) int64 strictly increasing capture times; a single pose means standing still.
        x_m, y_m, yaw_rad: (T,) float64.
    """

    t_us: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t_us, dtype=np.int64).reshape(-1)
        object.__setattr__(self, "t_us", t)
        for name in ("x_m", "y_m", "yaw_rad"):
            arr = frozen_array(getattr(self, name), np.float64, None, f"EgoTrack.{name}")
            if len(arr) != len(t):
                raise MessageError(f"EgoTrack.{name}: expected {len(t)} values like t_us, got {len(arr)}")
            object.__setattr__(self, name, arr)
        if len(t) == 0 or np.any(np.diff(t) <= 0):
            raise MessageError(f"EgoTrack.t_us: expected strictly increasing times, got {t.tolist()[:5]}")

    @staticmethod
    def constant(
        t0_us: int,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        speed_mps: float = 0.0,
        yaw_rate_radps: float = 0.0,
        duration_us: int = 100_000,
    ) -> EgoTrack:
        """A track at constant speed and yaw rate from ``t0_us`` over ``duration_us`` (11 samples)."""
        t = t0_us + np.linspace(0, duration_us, 11).round().astype(np.int64)
        dt = (t - t0_us) * 1e-6
        yaw = yaw_rad + yaw_rate_radps * dt
        if abs(yaw_rate_radps) < 1e-9:
            x = x_m + speed_mps * dt * math.cos(yaw_rad)
            y = y_m + speed_mps * dt * math.sin(yaw_rad)
        else:
            rad = speed_mps / yaw_rate_radps
            x = x_m + rad * (np.sin(yaw) - math.sin(yaw_rad))
            y = y_m - rad * (np.cos(yaw) - math.cos(yaw_rad))
        return EgoTrack(t_us=t, x_m=x, y_m=y, yaw_rad=yaw)

    def at(self, t_us: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, yaw) at the given times; held at the ends outside the track."""
        t = np.asarray(t_us, dtype=np.float64)
        tt = self.t_us.astype(np.float64)
        return np.interp(t, tt, self.x_m), np.interp(t, tt, self.y_m), np.interp(t, tt, self._yaw_unwrapped)

    @property
    def _yaw_unwrapped(self) -> np.ndarray:
        yaw = self.yaw_rad
        if len(yaw) < 2 or np.all(np.abs(np.diff(yaw)) < math.pi):
            return yaw
        return np.unwrap(yaw)
