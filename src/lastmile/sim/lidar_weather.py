"""How weather acts on LiDAR returns: extinction, precipitation echoes, dropouts, snow on the road edge.

The LiDAR reads the same :class:`lastmile.sim.weather.Weather` setting as the radar; an ``intensity``
in [0, 2] scales the precipitation and fog terms (1 = the reference event in the table below).

Reference values (intensity 1) and where they come from:

=========  ==============  =================  ==========  ==========  ==============  ============
weather    extinction 1/m  echoes / 1000 rays  echo mean   dropout     range noise x   snow bank m
=========  ==============  =================  ==========  ==========  ==============  ============
clear      0.0             0.0                -           0.0         1.0             0.0
rain       0.006           2.0                2.5 m       0.01        1.5             0.0
snow       0.012           12.0               3.0 m       0.03        2.0             0.6
fog        0.035           0.5                2.0 m       0.02        1.2             0.0
=========  ==============  =================  ==========  ==========  ==============  ============

- Extinction alpha: fog of 85 m meteorological visibility has alpha = 3.0 / 85 m ~ 0.035 /m
  (Koschmieder); heavy rain (~25 mm/h) ~ 0.006 /m and moderate snowfall ~ 0.012 /m at 905 nm
  (Rasshofer et al. 2011, Filgueira et al. 2017). The two-way loss exp(-2 alpha R) multiplies the
  returned power, so weak targets drop out first: in fog a 10 % target is lost beyond ~32 m.
- Echoes: falling drops and flakes return single points concentrated within a few metres of the
  window (Charron et al. 2018: snow points mostly under 5-10 m, low intensity); with 12 per 1000 rays
  the whole rig shows ~460 flake points per frame in snow (rays into the shuttle's body get none).
- Wet surfaces (rain): a water film halves the road's and sidewalk's diffuse return (wet asphalt
  returns 30-60 % of dry at 905 nm), so far ground points fade first.
- Snow bank: ploughed snow fills the curb step; ``snow_cover_lane_m`` more of the lane lies under
  snow at curb height (a scenario setting, 0 by default).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from lastmile.core.errors import ConfigError
from lastmile.sim.lidar_ground import check_bank
from lastmile.sim.weather import Weather


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarWeather:
    """Weather terms of the LiDAR model (units in the names; see the module table).

    Attributes:
        extinction_per_m: atmospheric extinction alpha; two-way power loss exp(-2 alpha R).
        echoes_per_kray: mean precipitation echoes per 1000 fired rays (Poisson per sweep).
        echo_mean_range_m: mean of the exponential range distribution of echoes (from ``min_range``).
        echo_max_range_m: echoes farther than this are not produced.
        dropout_prob: chance a real return is lost (wet window, scattering), per point.
        range_noise_factor: multiplies the sensor's range noise.
        snow_bank_width_m: width of the slope from curb height down to the road next to a curb.
        snow_cover_lane_m: width of lane next to the curb covered at curb height.
        wet_surface_factor: multiplies the road's and sidewalk's diffuse reflectivity (a film of
            water reflects the beam forward, away from the sensor: dimmer and shorter ground returns).
    """

    extinction_per_m: float = 0.0
    echoes_per_kray: float = 0.0
    echo_mean_range_m: float = 2.5
    echo_max_range_m: float = 15.0
    dropout_prob: float = 0.0
    range_noise_factor: float = 1.0
    snow_bank_width_m: float = 0.0
    snow_cover_lane_m: float = 0.0
    wet_surface_factor: float = 1.0

    def __post_init__(self) -> None:
        for name in (
            "extinction_per_m",
            "echoes_per_kray",
            "echo_mean_range_m",
            "echo_max_range_m",
            "dropout_prob",
            "range_noise_factor",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"LidarWeather.{name}: expected a finite number >= 0, got {value!r}")
        if not (math.isfinite(self.wet_surface_factor) and 0.0 < self.wet_surface_factor <= 1.0):
            raise ConfigError(
                f"LidarWeather.wet_surface_factor: expected a number in (0, 1], got {self.wet_surface_factor}"
            )
        if self.dropout_prob >= 1.0:
            raise ConfigError(
                f"LidarWeather.dropout_prob: expected a probability < 1, got {self.dropout_prob}"
            )
        if self.echo_mean_range_m <= 0.0:
            raise ConfigError(f"LidarWeather.echo_mean_range_m: expected > 0, got {self.echo_mean_range_m}")
        check_bank(self.snow_bank_width_m, self.snow_cover_lane_m)

    @property
    def snow_on_road(self) -> bool:
        return self.snow_bank_width_m > 0.0 or self.snow_cover_lane_m > 0.0

    @property
    def bare_road_from_curb_m(self) -> float:
        """How far from the curb the road surface is bare again (0 without snow on the road).

        Ground truth for boundary benchmarks: under snow the drivable edge a LiDAR can see is here,
        not at the buried curb (WATonoBus fig. 5 shows the same offset between map curb and snow).
        """
        return self.snow_cover_lane_m + self.snow_bank_width_m


LIDAR_WEATHER: dict[Weather, LidarWeather] = {
    Weather.CLEAR: LidarWeather(),
    Weather.RAIN: LidarWeather(
        extinction_per_m=0.006,
        echoes_per_kray=2.0,
        dropout_prob=0.01,
        range_noise_factor=1.5,
        wet_surface_factor=0.5,
    ),
    Weather.SNOW: LidarWeather(
        extinction_per_m=0.012,
        echoes_per_kray=12.0,
        echo_mean_range_m=3.0,
        dropout_prob=0.03,
        range_noise_factor=2.0,
        snow_bank_width_m=0.6,
    ),
    Weather.FOG: LidarWeather(
        extinction_per_m=0.035,
        echoes_per_kray=0.5,
        echo_mean_range_m=2.0,
        dropout_prob=0.02,
        range_noise_factor=1.2,
    ),
}


def lidar_weather(
    weather: Weather | str, intensity: float = 1.0, snow_cover_lane_m: float = 0.0
) -> LidarWeather:
    """The LiDAR terms of ``weather`` at ``intensity`` (0: none of it, 1: the table, 2: twice as heavy).

    Raises:
        ConfigError: unknown weather name, or an intensity outside [0, 2], or a bad lane cover.
    """
    if isinstance(weather, str):
        try:
            weather = Weather(weather)
        except ValueError:
            raise ConfigError(
                f"lidar weather: expected one of {[w.value for w in Weather]}, got {weather!r}"
            ) from None
    if not (isinstance(intensity, int | float) and math.isfinite(intensity) and 0.0 <= intensity <= 2.0):
        raise ConfigError(f"lidar weather intensity: expected a number in [0, 2], got {intensity!r}")
    ref = LIDAR_WEATHER[weather]
    return replace(
        ref,
        extinction_per_m=ref.extinction_per_m * intensity,
        echoes_per_kray=ref.echoes_per_kray * intensity,
        dropout_prob=min(0.5, ref.dropout_prob * intensity),
        range_noise_factor=1.0 + (ref.range_noise_factor - 1.0) * intensity,
        wet_surface_factor=1.0 - (1.0 - ref.wet_surface_factor) * min(intensity, 1.0),
        snow_cover_lane_m=snow_cover_lane_m,
    )
