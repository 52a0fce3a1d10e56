"""NUS's AMCL as a localization mode of the stack: its settings and the particle set as a pose measurement.

The particle filter (:mod:`lastmile.localization.particle_filter`) runs on the occupancy map that
``lastmile map build`` writes beside the point-cloud map (:mod:`lastmile.localization.occupancy_map`),
fed each LiDAR frame's planar scan and the odometry between frames. Its weighted mean and covariance are
fused into the inertial EKF like a scan match (:class:`ScanMatchMeasurement`: only the directions whose
sigma is within ``max_direction_std_m``, through the EKF's Mahalanobis gate: along a straight street the
particles spread along the road while the across-road position stays sharp), and only while its
random-particle injection (the recovery that a lost filter triggers) is below ``max_random_injection``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lastmile.core.errors import ConfigError
from lastmile.localization.occupancy_map import MAX_HEIGHT_M, MIN_HEIGHT_M, read_grid
from lastmile.localization.particle_filter import AmclConfig, OccupancyGrid


@dataclass(frozen=True, slots=True, kw_only=True)
class AmclSettings:
    """``[stack.amcl]``: the occupancy map and the particle filter of the ``amcl`` localization mode.

    Attributes:
        map: the occupancy map (map_server YAML from ``lastmile map build``), a path.
        seed: the particle filter's random stream (one seed repeats a run bit for bit).
        min_height_m, max_height_m: the height band of the planar scan (as the map's), m.
        max_direction_std_m: a horizontal direction whose sigma exceeds this is not fused, m.
        max_yaw_std_rad: nor the heading when its sigma exceeds this, rad.
        max_random_injection: while the filter injects more random particles than this share (it
            is recovering from a lost pose), nothing is fused.
        reseed_after: after this many filter updates in a row refused by the EKF's gate or
            recovering, while RTK holds the EKF, the particles restart at the EKF's pose (one second of
            10 Hz frames).
        filter: the particle filter's parameters (``[stack.amcl.filter]``, ROS amcl's defaults).
    """

    map: str = ""
    seed: int = 0
    min_height_m: float = MIN_HEIGHT_M
    max_height_m: float = MAX_HEIGHT_M
    max_direction_std_m: float = 0.3
    max_yaw_std_rad: float = math.radians(3.0)
    max_random_injection: float = 0.05
    reseed_after: int = 10
    filter: AmclConfig = field(default_factory=AmclConfig)

    def __post_init__(self) -> None:
        for name in ("max_direction_std_m", "max_yaw_std_rad", "max_height_m"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"stack.amcl.{name}: expected a positive number, got {value!r}")
        if not 0.0 <= self.min_height_m < self.max_height_m:
            raise ConfigError(
                f"stack.amcl.min_height_m: expected in [0, max_height_m), got {self.min_height_m}"
            )
        if self.reseed_after < 1:
            raise ConfigError(f"stack.amcl.reseed_after: expected >= 1, got {self.reseed_after}")
        if not 0.0 < self.max_random_injection <= 1.0:
            raise ConfigError(
                f"stack.amcl.max_random_injection: expected (0, 1], got {self.max_random_injection}"
            )

    def load_map(self) -> OccupancyGrid:
        """The occupancy map; one line (a ``ConfigError`` naming the key) when none is given or it is bad."""
        if not self.map:
            raise ConfigError(
                "stack.amcl.map: expected the occupancy map (a .yaml from `lastmile map build`), got none"
            )
        try:
            return read_grid(self.map)
        except Exception as exc:  # MapError and anything a broken file raises: one line
            raise ConfigError(f"stack.amcl.map: {exc}") from None
