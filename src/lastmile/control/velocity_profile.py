"""aUToronto's velocity profile generator (7.2.2): a trapezoidal profile over the local path.

The profile accelerates from the current speed at a_max, cruises at the speed limit lowered by the
curvature limit v = sqrt(a_lat / |kappa|), and decelerates at d_max so that the local path ends at
0 m/s (aUToronto: "critical for safety reasons") or at a stop point inside it. Speeds come from a
forward pass (reachable from the current speed) and a backward pass (able to stop in time); the
acceleration along the profile is the feed-forward of the cascaded speed controller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import ConfigError, MessageError


@dataclass(frozen=True, slots=True, kw_only=True)
class VelocityProfileConfig:
    """Limits of the profile (defaults inside Snow Lion's measured comfort envelope, -1.83 to 1.12 m/s^2).

    Attributes:
        max_accel_mps2: a_max of the acceleration ramp.
        max_decel_mps2: d_max of the deceleration ramp (positive number).
        max_lateral_accel_mps2: curvature limit v = sqrt(a_lat / |kappa|).
        stop_at_end: the profile reaches 0 m/s at the end of the local path.
    """

    max_accel_mps2: float = 0.8
    max_decel_mps2: float = 1.2
    max_lateral_accel_mps2: float = 1.0
    stop_at_end: bool = True

    def __post_init__(self) -> None:
        for name in ("max_accel_mps2", "max_decel_mps2", "max_lateral_accel_mps2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"VelocityProfileConfig.{name}: expected a positive number, got {value}")


@dataclass(frozen=True, slots=True, kw_only=True)
class VelocityProfile:
    """Speeds and accelerations along a path.

    Attributes:
        s_m: (M,) float64 stations, increasing.
        speed_mps: (M,) float64 target speed at each station.
        accel_mps2: (M,) float64 acceleration from each station to the next (last repeats).
    """

    s_m: np.ndarray
    speed_mps: np.ndarray
    accel_mps2: np.ndarray

    def at(self, s_m: float) -> tuple[float, float]:
        """(speed, acceleration) at station ``s_m`` (speed interpolated, clamped at the ends)."""
        v = float(np.interp(s_m, self.s_m, self.speed_mps))
        i = int(np.clip(np.searchsorted(self.s_m, s_m, side="right") - 1, 0, len(self.s_m) - 1))
        return v, float(self.accel_mps2[i])


def trapezoidal_profile(
    s_m: np.ndarray,
    curvature_1pm: np.ndarray,
    speed_limit_mps: float | np.ndarray,
    v0_mps: float,
    config: VelocityProfileConfig | None = None,
    stop_s_m: float | None = None,
) -> VelocityProfile:
    """The trapezoidal profile over stations ``s_m`` (M,) with curvature (M,) and speed limits.

    ``v0_mps`` is the current speed at ``s_m[0]``; ``stop_s_m`` (optional) is a station where the
    vehicle must be at rest (the profile is 0 from there on).

    Raises:
        MessageError: mismatched shapes, non-increasing stations, or a non-finite input.
    """
    c = config or VelocityProfileConfig()
    s = np.asarray(s_m, dtype=np.float64)
    kappa = np.asarray(curvature_1pm, dtype=np.float64)
    if s.ndim != 1 or len(s) < 2 or kappa.shape != s.shape:
        raise MessageError(
            f"trapezoidal_profile: expected (M,) stations and curvatures with M >= 2, got {s.shape} and "
            f"{kappa.shape}"
        )
    ds = np.diff(s)
    if not (np.all(np.isfinite(s)) and np.all(ds > 0.0)):
        raise MessageError("trapezoidal_profile: expected finite, strictly increasing stations")
    if not (math.isfinite(v0_mps) and v0_mps >= 0.0):
        raise MessageError(f"trapezoidal_profile: expected a current speed >= 0 m/s, got {v0_mps}")
    limit = np.broadcast_to(np.asarray(speed_limit_mps, dtype=np.float64), s.shape)
    v = np.minimum(limit, np.sqrt(c.max_lateral_accel_mps2 / np.maximum(np.abs(kappa), 1e-9)))
    if stop_s_m is not None:
        v = np.where(s >= stop_s_m, 0.0, v)
    if c.stop_at_end:
        v[-1] = 0.0
    # Forward: reachable from the current speed at a_max (a vehicle already above the limit is given
    # the limit: the speed loop then brakes toward it). v_i^2 = min_j<=i (v_j^2 + 2 a (s_i - s_j)),
    # a running minimum rather than a loop.
    v2 = v * v
    v2[0] = min(v0_mps, v[0]) ** 2
    a2, d2 = 2.0 * c.max_accel_mps2, 2.0 * c.max_decel_mps2
    fwd2 = np.minimum.accumulate(v2 - a2 * s) + a2 * s
    # Backward: able to slow to every later limit at d_max: v_i^2 = min_j>=i (v_j^2 + 2 d (s_j - s_i)).
    out2 = np.minimum.accumulate((fwd2 + d2 * s)[::-1])[::-1] - d2 * s
    out = np.minimum(np.sqrt(np.maximum(out2, 0.0)), v)  # never above a limit by rounding
    out[0] = min(out[0], v0_mps)
    accel = np.empty_like(out)
    accel[:-1] = (out[1:] ** 2 - out[:-1] ** 2) / (2.0 * ds)
    accel[-1] = accel[-2]
    return VelocityProfile(s_m=s, speed_mps=out, accel_mps2=accel)
