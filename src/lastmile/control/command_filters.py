"""Controller output stages (aUToronto 7.2.5): a first-order low-pass filter and a rate limiter."""

from __future__ import annotations

import math

from lastmile.core.errors import ConfigError


class LowPassFilter:
    """First-order low-pass y' = (u - y) / tau, discretised exactly for a held input (alpha = 1 - e^-dt/tau).

    ``tau_s == 0`` passes the input through.
    """

    def __init__(self, tau_s: float) -> None:
        if not (math.isfinite(tau_s) and tau_s >= 0.0):
            raise ConfigError(f"LowPassFilter.tau_s: expected a finite number >= 0 s, got {tau_s}")
        self.tau_s = tau_s
        self.value: float | None = None

    def reset(self, value: float | None = None) -> None:
        self.value = value

    def step(self, dt_s: float, u: float) -> float:
        if self.value is None or self.tau_s == 0.0:
            self.value = u
        else:
            self.value += (u - self.value) * (1.0 - math.exp(-dt_s / self.tau_s))
        return self.value


class RateLimiter:
    """Limits how fast a command may move: at most ``rise_per_s * dt`` up, ``fall_per_s * dt`` down."""

    def __init__(self, rise_per_s: float, fall_per_s: float | None = None) -> None:
        fall = rise_per_s if fall_per_s is None else fall_per_s
        for name, value in (("rise_per_s", rise_per_s), ("fall_per_s", fall)):
            if not (value > 0.0):
                raise ConfigError(f"RateLimiter.{name}: expected a positive rate, got {value}")
        self.rise_per_s = rise_per_s
        self.fall_per_s = fall
        self.value: float | None = None

    def reset(self, value: float | None = None) -> None:
        self.value = value

    def step(self, dt_s: float, u: float) -> float:
        if self.value is None:
            self.value = u
        else:
            self.value = min(max(u, self.value - self.fall_per_s * dt_s), self.value + self.rise_per_s * dt_s)
        return self.value


class SteeringOutput:
    """Clamp to the steering range, rate-limit to the actuator's rate, then low-pass (in that order)."""

    def __init__(self, max_steer_rad: float, max_rate_radps: float, tau_s: float) -> None:
        self.max_steer_rad = max_steer_rad
        self._rate = RateLimiter(max_rate_radps)
        self._lowpass = LowPassFilter(tau_s)

    def reset(self) -> None:
        self._rate.reset()
        self._lowpass.reset()

    def step(self, dt_s: float, delta_rad: float) -> float:
        delta = min(max(delta_rad, -self.max_steer_rad), self.max_steer_rad)
        return self._lowpass.step(dt_s, self._rate.step(dt_s, delta))
