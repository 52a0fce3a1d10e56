"""Snow Lion's speed constraints along the path: curvature (its eq. 1), pedestrian clearance (eq. 2), stop.

Eq. (1): v(s) <= sqrt(a_lat,max / |kappa(s)|). Eq. (2): a piecewise-linear limit on the clearance c to
pedestrians (the vehicle's shape taken into account): v_min below delta_min, rising linearly to v_mdn at
delta_mdn and to v_max at delta_max, v_max beyond. The terminal limit brings the vehicle to rest at the
end of a truncated reference route. Snow Lion publishes the form, not its thresholds; the defaults below
are ours and say why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.curve_speed import curvature_speed_limit_mps
from lastmile.core.errors import ConfigError, MessageError


@dataclass(frozen=True, slots=True, kw_only=True)
class ClearanceSpeedConfig:
    """Thresholds and speeds of eq. (2).

    Attributes:
        delta_min_m, delta_mdn_m, delta_max_m: clearance thresholds (increasing). 0.5 m is the clearance
            the potential-field planner keeps; 3 m is a lane's width, beyond which a pedestrian is not
            in the shuttle's way.
        v_min_mps, v_mdn_mps, v_max_mps: the limits at and beyond them: walking pace (1 m/s) closest,
            9 km/h (Snow Lion's "high speed" mark in Table 2) at the middle threshold, and the
            shuttle's 20 km/h beyond.
    """

    delta_min_m: float = 0.5
    delta_mdn_m: float = 1.5
    delta_max_m: float = 3.0
    v_min_mps: float = 1.0
    v_mdn_mps: float = 2.5
    v_max_mps: float = 20.0 / 3.6

    def __post_init__(self) -> None:
        if not (0.0 <= self.delta_min_m < self.delta_mdn_m < self.delta_max_m):
            raise ConfigError(
                f"ClearanceSpeedConfig: expected 0 <= delta_min_m < delta_mdn_m < delta_max_m, got "
                f"{self.delta_min_m}, {self.delta_mdn_m}, {self.delta_max_m}"
            )
        if not (0.0 <= self.v_min_mps <= self.v_mdn_mps <= self.v_max_mps):
            raise ConfigError(
                f"ClearanceSpeedConfig: expected 0 <= v_min_mps <= v_mdn_mps <= v_max_mps, got "
                f"{self.v_min_mps}, {self.v_mdn_mps}, {self.v_max_mps}"
            )


def clearance_speed_limit_mps(clearance_m: np.ndarray, c: ClearanceSpeedConfig | None = None) -> np.ndarray:
    """Eq. (2) at each clearance (m; infinite where no pedestrian is near)."""
    c = c or ClearanceSpeedConfig()
    x = np.asarray(clearance_m, dtype=np.float64)
    if np.any(np.isnan(x)):
        raise MessageError("clearance_speed_limit_mps: expected clearances in m, got NaN")
    # np.interp is exactly the piecewise lerp of eq. (2), flat outside [delta_min, delta_max].
    return np.interp(
        x, [c.delta_min_m, c.delta_mdn_m, c.delta_max_m], [c.v_min_mps, c.v_mdn_mps, c.v_max_mps]
    )


def terminal_speed_limit_mps(s_m: np.ndarray, stop_s_m: float | None, max_decel_mps2: float) -> np.ndarray:
    """The limit that stops the vehicle at ``stop_s_m``: sqrt(2 d (s_stop - s)), zero from there on."""
    s = np.asarray(s_m, dtype=np.float64)
    if stop_s_m is None or not math.isfinite(stop_s_m):
        return np.full(s.shape, np.inf)
    return np.sqrt(2.0 * max_decel_mps2 * np.maximum(stop_s_m - s, 0.0))


def combined_speed_limit_mps(
    s_m: np.ndarray,
    curvature_1pm: np.ndarray,
    route_limit_mps: float,
    max_lateral_accel_mps2: float,
    clearance_m: np.ndarray | None = None,
    clearance: ClearanceSpeedConfig | None = None,
    stop_s_m: float | None = None,
    max_decel_mps2: float = 1.2,
) -> np.ndarray:
    """The lowest of the route's limit, eq. (1), eq. (2) and the terminal limit at each station."""
    v = np.minimum(route_limit_mps, curvature_speed_limit_mps(curvature_1pm, max_lateral_accel_mps2))
    if clearance_m is not None:
        v = np.minimum(v, clearance_speed_limit_mps(clearance_m, clearance))
    return np.minimum(v, terminal_speed_limit_mps(s_m, stop_s_m, max_decel_mps2))
