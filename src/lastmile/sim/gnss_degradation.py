"""Simulated GNSS, IMU and wheel-odometry degradation: fix quality, multipath, outages, drift, slip.

The scenario's ``[gnss]`` table selects them (:mod:`lastmile.sim.gnss_scenario`); the sensor suite then
takes its GNSS solution and wheel speed from here. Each model is driven by its own
``numpy.random.Generator`` (one seed spawn per component), so a run repeats bit for bit.

- :class:`GnssDegradation`: a receiver's solution of the antenna: RTK fixed by default; RTK float with a
  Gauss-Markov multipath bias near the map's buildings (largest at the facade, gone at
  ``multipath_range_m``); no fix or a chosen lower quality inside outage regions (tunnels, underpasses,
  tree canopy) and during heavy-snow outages (Poisson starts, exponential lengths); white noise at the
  quality's datasheet accuracy; a reported covariance that is optimistic by ``reported_sigma_factor`` as
  receivers' formal ones are.
- :class:`ImuErrors`: a gyro turn-on bias with a random walk (INS bias drift), a gyro scale error, an
  accelerometer bias and white noise.
- :class:`WheelSlip`: on snow, the wheel speed over-reads (spin) by a scale error and a slip noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.gnss_messages import ACCURACY_FLOOR_M, GnssFix, GnssQuality
from lastmile.core.stamp import Stamp


@dataclass(frozen=True, slots=True, kw_only=True)
class OutageRegion:
    """A map region where the solution degrades.

    Attributes:
        polygon: (N, 2) outline in the map frame, m; None: everywhere (an outage window in time).
        quality: the best solution available inside; None: no fix at all.
        start_s, end_s: when the region is active (simulated seconds); default always.
    """

    polygon: np.ndarray | None
    quality: GnssQuality | None = None
    start_s: float = 0.0
    end_s: float = math.inf


@dataclass(frozen=True, slots=True, kw_only=True)
class GnssDegradationConfig:
    """Parameters of :class:`GnssDegradation` (sources on each).

    Attributes:
        multipath_range_m: a facade closer than this reflects signals into the solution, m (urban
            canyon studies: tens of metres; a campus building, 15 m).
        multipath_std_m: one-sigma multipath bias at the facade, m, falling linearly to 0 at the range
            (code multipath of metres, carrier-phase RTK degraded to float at decimetres: 0.5 m).
        multipath_correlation_s: correlation time of that bias, s (it changes as satellite geometry and
            the vehicle move: 10 s).
        snow_outages_per_hour: heavy snow on the antenna: outages start as a Poisson process.
        snow_outage_mean_s: their mean length, s (exponential).
        reported_sigma_factor: the receiver reports this times the real sigma (formal covariances are
            optimistic: 0.5).
        regions: outage regions.
    """

    multipath_range_m: float = 15.0
    multipath_std_m: float = 0.5
    multipath_correlation_s: float = 10.0
    snow_outages_per_hour: float = 6.0
    snow_outage_mean_s: float = 30.0
    reported_sigma_factor: float = 0.5
    regions: tuple[OutageRegion, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        for name in (
            "multipath_range_m",
            "multipath_correlation_s",
            "snow_outage_mean_s",
            "reported_sigma_factor",
        ):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"GnssDegradationConfig.{name}: expected a positive number, got {value!r}")
        for name in ("multipath_std_m", "snow_outages_per_hour"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise ConfigError(f"GnssDegradationConfig.{name}: expected a number >= 0, got {value!r}")
        for region in self.regions:
            if region.polygon is None:
                continue
            poly = np.asarray(region.polygon)
            if poly.ndim != 2 or poly.shape[1] != 2 or poly.shape[0] < 3:
                raise ConfigError(f"OutageRegion.polygon: expected (N >= 3, 2), got shape {poly.shape}")


def _inside(polygon: np.ndarray, x: float, y: float) -> bool:
    """Even-odd rule."""
    px, py = polygon[:, 0], polygon[:, 1]
    qx, qy = np.roll(px, -1), np.roll(py, -1)
    crosses = (py > y) != (qy > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        at = px + (y - py) * (qx - px) / (qy - py)
    return bool(np.count_nonzero(crosses & (x < at)) % 2)


def distance_to_outlines_m(outlines: list[np.ndarray], x: float, y: float) -> float:
    """Distance from (x, y) to the nearest edge of any closed (N, 2) outline, m (inf without outlines)."""
    best = math.inf
    p = np.array([x, y])
    for poly in outlines:
        a = poly
        b = np.roll(poly, -1, axis=0)
        ab = b - a
        t = np.clip(
            np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0.0, 1.0
        )
        d = np.hypot(*(a + t[:, None] * ab - p).T)
        best = min(best, float(d.min()))
    return best


class GnssDegradation:
    """The receiver: one solution per call, of the antenna at its true position."""

    def __init__(
        self, config: GnssDegradationConfig, buildings: list[np.ndarray], rng: np.random.Generator
    ) -> None:
        """Args:
        buildings: building outlines, (N, 2) each, map frame (``HDMap.areas`` of subtype building).
        rng: this component's generator.
        """
        self.config = config
        self._buildings = [np.asarray(b, dtype=float) for b in buildings]
        self._rng = rng
        self._bias = np.zeros(2)
        self._last_s: float | None = None
        self._snow_outage_until_s = -math.inf

    def fix(self, stamp: Stamp, x_m: float, y_m: float, heavy_snow: bool = False) -> GnssFix | None:
        """The solution at ``stamp`` (None: no fix), for an antenna truly at (x_m, y_m)."""
        c, rng = self.config, self._rng
        t_s = stamp / 1e6
        dt = 0.0 if self._last_s is None else max(t_s - self._last_s, 0.0)
        self._last_s = t_s
        starts = heavy_snow and t_s >= self._snow_outage_until_s and c.snow_outages_per_hour > 0
        if starts and rng.random() < 1.0 - math.exp(-c.snow_outages_per_hour / 3600.0 * dt):
            self._snow_outage_until_s = t_s + float(rng.exponential(c.snow_outage_mean_s))
        if t_s < self._snow_outage_until_s:
            return None
        quality: GnssQuality | None = GnssQuality.RTK_FIXED
        for region in c.regions:
            if region.start_s <= t_s < region.end_s and (
                region.polygon is None or _inside(np.asarray(region.polygon), x_m, y_m)
            ):
                quality = region.quality
                if quality is None:
                    return None
        near = distance_to_outlines_m(self._buildings, x_m, y_m)
        strength = max(0.0, 1.0 - near / c.multipath_range_m)
        fade = math.exp(-dt / c.multipath_correlation_s)
        sigma = c.multipath_std_m * strength
        self._bias = fade * self._bias + rng.normal(0.0, sigma * math.sqrt(1.0 - fade * fade), 2)
        if strength > 0 and quality is GnssQuality.RTK_FIXED:
            quality = GnssQuality.RTK_FLOAT  # reflected carrier phase: the ambiguities do not fix
        assert quality is not None
        white = ACCURACY_FLOOR_M[quality]
        noise = rng.normal(0.0, white, 2) + (self._bias if strength > 0 else 0.0)
        real_var = white**2 + sigma**2
        reported = (c.reported_sigma_factor**2) * real_var
        return GnssFix(
            stamp=stamp,
            x_m=x_m + float(noise[0]),
            y_m=y_m + float(noise[1]),
            var_xx_m2=reported,
            var_xy_m2=0.0,
            var_yy_m2=reported,
            quality=quality,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuErrorConfig:
    """An industrial MEMS IMU (ADIS16470 datasheet class) as the simulator's truth of IMU errors.

    Attributes:
        gyro_bias_std_radps: turn-on bias, one sigma (drawn once), rad/s.
        gyro_bias_walk_radps: bias random walk, rad/s per sqrt(s) (INS bias drift).
        gyro_scale_std: scale-factor error, one sigma (drawn once).
        gyro_noise_radps: white noise density, rad/s per sqrt(Hz).
        accel_bias_std_mps2: accelerometer turn-on bias, m/s^2.
        accel_noise_mps2: white noise density, m/s^2 per sqrt(Hz).
    """

    gyro_bias_std_radps: float = math.radians(0.2)
    gyro_bias_walk_radps: float = math.radians(8.0 / 3600.0) / 10.0
    gyro_scale_std: float = 0.005
    gyro_noise_radps: float = math.radians(0.008)
    accel_bias_std_mps2: float = 0.05
    accel_noise_mps2: float = 6.2e-4 * 10.0


class ImuErrors:
    """Corrupts true yaw rate and longitudinal acceleration with a drifting bias, scale error and noise."""

    def __init__(self, config: ImuErrorConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._rng = rng
        self.gyro_bias_radps = float(rng.normal(0.0, config.gyro_bias_std_radps))
        self.gyro_scale = float(rng.normal(0.0, config.gyro_scale_std))
        self.accel_bias_mps2 = float(rng.normal(0.0, config.accel_bias_std_mps2))

    def corrupt(self, dt_s: float, yaw_rate_radps: float, accel_x_mps2: float) -> tuple[float, float]:
        """One sample at ``dt_s`` after the previous: (measured yaw rate, measured acceleration)."""
        c, rng = self.config, self._rng
        self.gyro_bias_radps += float(rng.normal(0.0, c.gyro_bias_walk_radps * math.sqrt(max(dt_s, 0.0))))
        rate = 1.0 / max(dt_s, 1e-6)
        gyro = (1.0 + self.gyro_scale) * yaw_rate_radps + self.gyro_bias_radps
        gyro += float(rng.normal(0.0, c.gyro_noise_radps * math.sqrt(rate / 2.0)))
        accel = (
            accel_x_mps2
            + self.accel_bias_mps2
            + float(rng.normal(0.0, c.accel_noise_mps2 * math.sqrt(rate / 2.0)))
        )
        return gyro, accel


@dataclass(frozen=True, slots=True, kw_only=True)
class WheelSlip:
    """Wheel-speed error on a slippery surface.

    Attributes:
        scale_error: the wheels over-read by this share while driving (spin under traction on snow).
        slip_std: and a slip noise of this share of the speed, one sigma.
    """

    scale_error: float = 0.03
    slip_std: float = 0.02

    def corrupt(self, speed_mps: float, rng: np.random.Generator) -> float:
        if speed_mps <= 0.0:
            return speed_mps
        return speed_mps * (1.0 + self.scale_error + float(rng.normal(0.0, self.slip_std)))
