"""The speed a curve allows, v = sqrt(a_lat / |kappa|) (Snow Lion's eq. 1), for planning and decision."""

from __future__ import annotations

import numpy as np

from lastmile.core.errors import ConfigError


def curvature_speed_limit_mps(curvature_1pm: np.ndarray, max_lateral_accel_mps2: float) -> np.ndarray:
    """sqrt(a_lat / |kappa|) at each curvature (1/m); infinite on straight road."""
    if not max_lateral_accel_mps2 > 0.0:
        raise ConfigError(f"curvature_speed_limit_mps: expected a_lat > 0, got {max_lateral_accel_mps2}")
    k = np.abs(np.asarray(curvature_1pm, dtype=np.float64))
    with np.errstate(divide="ignore"):
        return np.where(k > 1e-9, np.sqrt(max_lateral_accel_mps2 / np.maximum(k, 1e-300)), np.inf)
