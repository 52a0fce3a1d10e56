"""GEM's height-map obstacle stop (its section V) as an option of the stack: ``[stack.occupancy_stop]``.

Each LiDAR rig frame the raw chain has processed gives the height map around the shuttle
(:func:`lastmile.perception.occupancy.height_map`: 0.25 m cells occupied where their points spread
over 0.07 m, points above the shuttle removed; the weather filter's noise left out, as the chain has it
anyway). The expected path is the bicycle model's arc for the measured wheel angles, widened to the
body plus a side clearance; the nearest occupied cell on it ahead of the front bumper, at distance d,
caps the speed at GEM's ``v = d / 5 - 1`` (0 within 5 m: full braking). The cap joins the others the
longitudinal controller obeys; it holds until the next rig frame.

It is GEM's baseline, with GEM's limits (the paper: "not a replacement for a safety driver"): a mapped
curb or a kerbside bollard on the arc stops the shuttle like an obstacle (at a pull-over the arc ends at
the curb), and it does not look at tracks, classes or the map. The default stack does not run it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.vehicle import VehicleGeometry
from lastmile.perception.occupancy import (
    HeightMapConfig,
    height_map,
    nearest_obstacle_on_path_m,
    obstacle_stop_speed_mps,
)
from lastmile.perception.pipeline import LidarPipelineResult


@dataclass(frozen=True, slots=True, kw_only=True)
class OccupancyStopSettings:
    """``[stack.occupancy_stop]``: GEM's grid and path; the table's presence turns the stop on.

    Attributes:
        grid: the height map and path length (GEM: 0.25 m cells, 0.07 m spread, 15 m ahead); its
            ``wheelbase_m`` and ``path_half_width_m`` are replaced by the shuttle's own (below).
        side_clearance_m: room beside the body the path is widened by. One grid cell: the least that
            still catches whatever the body would touch, given the grid's 0.25 m quantisation. GEM's
            own (a 1.3 m half path on its 1.40 m-wide GEM e4: 0.6 m) is wider than a 2 m shuttle has
            in a 3.2 m lane, where every curb beside it would stop it; GEM notes that its routes,
            too, needed "a smaller clearance ... to allow for passage between stationary obstacles".
    """

    grid: HeightMapConfig = field(default_factory=HeightMapConfig)
    side_clearance_m: float = HeightMapConfig().cell_m

    def __post_init__(self) -> None:
        if not (math.isfinite(self.side_clearance_m) and self.side_clearance_m >= 0.0):
            raise ConfigError(
                f"stack.occupancy_stop.side_clearance_m: expected a number >= 0, got {self.side_clearance_m}"
            )


@dataclass(slots=True)
class OccupancyStopStats:
    """Counters for the run's report."""

    frames: int = 0
    frames_capped: int = 0
    """Frames with an occupied cell on the path (a cap below cruise)."""
    nearest_m: float = math.inf
    """The nearest any frame put an occupied cell ahead of the bumper."""


class OccupancyStop:
    """The height map of each processed rig frame and the speed cap it implies."""

    def __init__(self, settings: OccupancyStopSettings, geometry: VehicleGeometry) -> None:
        self.geometry = geometry
        # The path is measured from the rear axle (the base frame's origin); GEM's 15 m are ahead of
        # the front bumper, and nothing beside the body counts (a curb the shuttle stands at).
        self.front_m = geometry.front_from_rear_axle_m
        self.grid = dataclasses.replace(
            settings.grid,
            wheelbase_m=geometry.wheelbase_m,
            path_half_width_m=geometry.width_m / 2.0 + settings.side_clearance_m,
            lookahead_m=settings.grid.lookahead_m + self.front_m,
            half_extent_m=max(settings.grid.half_extent_m, settings.grid.lookahead_m + self.front_m),
        )
        self.distance_m = math.inf
        self.stats = OccupancyStopStats()

    def update(self, result: LidarPipelineResult, steer_front_rad: float, steer_rear_rad: float) -> None:
        """The nearest occupied cell ahead on the arc of the measured wheel angles."""
        keep = ~np.asarray(result.noise, dtype=bool)
        grid = height_map(np.asarray(result.cloud.points[keep, :3], dtype=np.float64), self.grid)
        # The rear axle's arc of a bicycle steering both axles: curvature (tan f - tan r) / wheelbase,
        # given to GEM's front-steer model as its equivalent front angle.
        steer_rad = math.atan(math.tan(steer_front_rad) - math.tan(steer_rear_rad))
        s_m = nearest_obstacle_on_path_m(grid, steer_rad, self.grid, min_s_m=self.front_m)
        self.distance_m = s_m - self.front_m
        st = self.stats
        st.frames += 1
        if math.isfinite(self.distance_m):
            st.frames_capped += 1
            st.nearest_m = min(st.nearest_m, self.distance_m)

    def cap_mps(self, cruise_mps: float) -> float:
        """GEM's v = d / 5 - 1 for the last frame's nearest obstacle, at most ``cruise_mps``."""
        return obstacle_stop_speed_mps(self.distance_m, cruise_mps)

    def counters(self) -> dict[str, int]:
        """The stack report's counters of this option."""
        st = self.stats
        return {
            "occupancy_stop_frames": st.frames,
            "occupancy_stop_frames_capped": st.frames_capped,
        }
