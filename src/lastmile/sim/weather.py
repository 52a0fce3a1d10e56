"""Weather as a setting the sensor models respond to; every rate is documented here."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from lastmile.core.errors import ConfigError


class Weather(Enum):
    CLEAR = "clear"
    RAIN = "rain"
    SNOW = "snow"
    FOG = "fog"


@dataclass(frozen=True, slots=True, kw_only=True)
class WeatherEffects:
    """How a weather degrades the sensors.

    Attributes:
        radar_range_factor: multiplies every radar's maximum range (precipitation attenuates 77 GHz).
        radar_detect_factor: multiplies the per-frame detection probability of a real object.
        radar_false_alarms_per_frame: mean (Poisson) clutter detections per radar frame (spray, flakes).
        radar_noise_factor: multiplies position and velocity noise.
        gnss_noise_factor: multiplies GNSS/INS position noise (multipath off wet or snowy surfaces).
        wheel_slip_std: relative speed noise of wheel odometry (slip on wet/snowy road).
    """

    radar_range_factor: float
    radar_detect_factor: float
    radar_false_alarms_per_frame: float
    radar_noise_factor: float
    gnss_noise_factor: float
    wheel_slip_std: float


# Values follow the direction and rough size of published 77 GHz radar degradation (heavy rain and wet
# snow cost 10-30 % of range and add clutter); fog barely affects radar but hurts optics (LiDAR, camera
# arrive in a later issue and read the same setting).
WEATHER_EFFECTS: dict[Weather, WeatherEffects] = {
    Weather.CLEAR: WeatherEffects(
        radar_range_factor=1.0,
        radar_detect_factor=1.0,
        radar_false_alarms_per_frame=0.05,
        radar_noise_factor=1.0,
        gnss_noise_factor=1.0,
        wheel_slip_std=0.003,
    ),
    Weather.RAIN: WeatherEffects(
        radar_range_factor=0.85,
        radar_detect_factor=0.95,
        radar_false_alarms_per_frame=0.3,
        radar_noise_factor=1.3,
        gnss_noise_factor=1.3,
        wheel_slip_std=0.01,
    ),
    Weather.SNOW: WeatherEffects(
        radar_range_factor=0.75,
        radar_detect_factor=0.9,
        radar_false_alarms_per_frame=0.5,
        radar_noise_factor=1.5,
        gnss_noise_factor=1.5,
        wheel_slip_std=0.02,
    ),
    Weather.FOG: WeatherEffects(
        radar_range_factor=0.95,
        radar_detect_factor=0.98,
        radar_false_alarms_per_frame=0.1,
        radar_noise_factor=1.1,
        gnss_noise_factor=1.0,
        wheel_slip_std=0.005,
    ),
}


def parse_weather(name: str) -> Weather:
    """The :class:`Weather` named ``name``; a clear error for anything else."""
    try:
        return Weather(name)
    except ValueError:
        raise ConfigError(f"weather: expected one of {[w.value for w in Weather]}, got {name!r}") from None
