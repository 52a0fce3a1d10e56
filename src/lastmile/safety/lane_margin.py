"""The lane margin along the route: how far the vehicle may be off its lane centre before it leaves it."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.hdmap.layers import SLayerDatabase


def lane_margin_along_route(layers: SLayerDatabase, vehicle_width_m: float) -> Callable[[float], float]:
    """Half the mapped lane width less half the vehicle's, at a route s, m (never below 0).

    Reid et al. 2019 ("Localization requirements for autonomous vehicles", SAE Int. J. CAV 2(3)) take
    this as the lateral alert limit: a position error beyond it may put the vehicle's side over the
    lane's edge.

    Raises:
        ConfigError: a vehicle width that is not positive.
    """
    if not vehicle_width_m > 0:
        raise ConfigError(f"lane margin: expected a positive vehicle width, got {vehicle_width_m!r}")
    width = layers.lane_left_d_m - layers.lane_right_d_m
    margin = np.maximum(0.5 * (width - vehicle_width_m), 0.0)

    def at(s_m: float) -> float:
        return float(margin[layers.record_index(s_m)])

    return at
