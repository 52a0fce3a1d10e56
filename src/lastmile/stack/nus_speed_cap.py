"""NUS's speed rule (its IV-B) as an option of the stack: ``[stack.nus_speed]``.

NUS's navigation keeps "a map of 50m x 50m with a grid cell size of 0.2m ... with the vehicle centered
on the map. Each cell in the map can have a 1 byte value. Initially, the cells in the map are marked as
unknown with a value of 255. Whenever an obstacle is observed, the map is updated with a cost value of
254 ... the cost is propagated radially outward with an exponential function." The speed set point is
the lower of a safe speed from the steering angle and one from "the normalized average cost along the
projection of the golf car within a fix distance" (:mod:`lastmile.control.nus_speed`).

Here each LiDAR rig frame the raw chain has processed updates a map-aligned grid that rolls with the
shuttle (recentred on its estimated pose, whole cells at a time, so that a cell keeps what it saw).
GEM's height map (:func:`lastmile.perception.occupancy.height_map`, reused at NUS's 0.2 m cells and
50 m span) marks the frame's cells whose points spread over 0.07 m as obstacles and cells holding
points but no obstacle as free; the newest observation of a cell replaces the older one, cells never
observed stay unknown (255), and a cell the grid rolls over starts unknown. One frame of a LiDAR rig
leaves most 0.2 m cells ahead without a point (rings are metres apart on the road), which is why the
map must roll rather than be rebuilt per frame. The obstacles (254) then have their cost fall off as
``252 exp(-k d)`` out to an inflation radius. NUS names neither constant; ours are the defaults of
ROS's ``costmap_2d`` inflation layer, whose byte values (254 lethal, 255 no information) NUS's map
uses: ``cost_scaling_factor`` 10 /m and ``inflation_radius`` 0.55 m. As there, inflation raises the
cost of observed cells only; an unknown cell stays unknown. The footprint projected ahead starts at
the front bumper (the body's own cells are the LiDARs' blind spot) and is the shuttle's width.

The rule's ``v_max`` is the speed the stack would otherwise drive at that instant (cruise, limits, the
lateral controller's cap): NUS's 2 m/s is its golf car's top speed, not ours. The steering angle is the
last odometry frame's measured wheel angles, as the front-steer equivalent of both axles; it is read at
every control step, the map's cost once per rig frame.

Limits: a cell is cleared only when a later frame puts a point in it (no ray tracing through free
space, unlike costmap_2d's obstacle layer), so a road user's trail stays until the ground under it is
seen again; the map is placed with the stack's own pose estimate, whose error smears it; the
projection is straight ahead along the heading, as NUS words it, not along the path. The default stack
does not run it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from lastmile.control.nus_speed import (
    LETHAL_COST,
    UNKNOWN_COST,
    CostGrid,
    NusSpeedConfig,
    cost_safe_speed_mps,
    footprint_mean_cost,
    steering_safe_speed_mps,
)
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import LocalizationEstimate
from lastmile.perception.occupancy import HeightMapConfig, height_map
from lastmile.perception.pipeline import LidarPipelineResult

#: ROS costmap_2d's INSCRIBED_INFLATED_OBSTACLE - 1: the highest inflated cost beside an obstacle.
_INFLATED_MAX_COST = 252


@dataclass(frozen=True, slots=True, kw_only=True)
class NusCostMapSettings:
    """``[stack.nus_speed.cost_map]``: NUS's rolling grid.

    Attributes:
        cell_m: cell size (NUS: 0.2 m).
        half_extent_m: the grid spans +/- this around the rear axle (NUS: 50 m x 50 m).
        height_threshold_m: point spread that marks a cell an obstacle (GEM's height map: 0.07 m).
        max_z_m: points above (over the shuttle's roof) are ignored.
        inflation_radius_m: how far an obstacle's cost reaches (costmap_2d's default, 0.55 m).
        cost_scaling_per_m: k of the exponential fall-off (costmap_2d's default, 10 /m).
    """

    cell_m: float = 0.2
    half_extent_m: float = 25.0
    height_threshold_m: float = HeightMapConfig().height_threshold_m
    max_z_m: float = HeightMapConfig().max_z_m
    inflation_radius_m: float = 0.55
    cost_scaling_per_m: float = 10.0

    def __post_init__(self) -> None:
        for name in (
            "cell_m",
            "half_extent_m",
            "height_threshold_m",
            "max_z_m",
            "inflation_radius_m",
            "cost_scaling_per_m",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ConfigError(f"stack.nus_speed.cost_map.{name}: expected a positive number, got {v}")

    def height_map_config(self) -> HeightMapConfig:
        """GEM's height map at this grid's cells and span."""
        return HeightMapConfig(
            cell_m=self.cell_m,
            height_threshold_m=self.height_threshold_m,
            half_extent_m=self.half_extent_m,
            max_z_m=self.max_z_m,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class NusSpeedSettings:
    """``[stack.nus_speed]``: the rule's constants and its cost map; the table's presence turns it on.

    Attributes:
        steer_decay_per_rad: v_steer = v_max exp(-k |delta|) (NUS gives the form only; 2 /rad, a third
            of v_max at the shuttle's 0.55 rad full lock).
        lookahead_m: the "fix distance" the footprint is projected ahead of the front bumper. NUS does
            not give it; :class:`NusSpeedConfig`'s 6 m covers the stop from 20 km/h at the
            longitudinal law's 3 m/s^2 deepest braking (5.56^2 / 2 / 3 = 5.1 m).
        unknown_is_lethal: count unknown cells as obstacles (conservative) or leave them out of the mean.
        cost_map: the grid.
    """

    steer_decay_per_rad: float = NusSpeedConfig().steer_decay_per_rad
    lookahead_m: float = NusSpeedConfig().lookahead_m
    unknown_is_lethal: bool = NusSpeedConfig().unknown_is_lethal
    cost_map: NusCostMapSettings = field(default_factory=NusCostMapSettings)

    def __post_init__(self) -> None:
        for name in ("steer_decay_per_rad", "lookahead_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ConfigError(f"stack.nus_speed.{name}: expected a positive number, got {v}")


def cost_grid(
    occupied: np.ndarray,
    observed: np.ndarray,
    origin_x_m: float,
    origin_y_m: float,
    settings: NusCostMapSettings,
) -> CostGrid:
    """NUS's byte map: 254 obstacles, inflated costs around them, 255 where nothing was ever observed.

    Args:
        occupied, observed: (H, W) bool, rows along y; obstacle cells, cells observed at all.
        origin_x_m, origin_y_m: the map position of the corner of cell (0, 0).
        settings: the cell size and inflation.
    """
    cost = np.zeros(occupied.shape, dtype=np.uint8)
    if occupied.any():
        # Euclidean distance (m) of every cell to the nearest obstacle cell.
        distance_m = ndimage.distance_transform_edt(~occupied, sampling=settings.cell_m)
        near = (distance_m > 0.0) & (distance_m <= settings.inflation_radius_m)
        inflated = _INFLATED_MAX_COST * np.exp(-settings.cost_scaling_per_m * distance_m[near])
        cost[near] = np.round(inflated).astype(np.uint8)
    cost[~observed] = UNKNOWN_COST
    cost[occupied] = LETHAL_COST
    return CostGrid(cost=cost, origin_x_m=origin_x_m, origin_y_m=origin_y_m, cell_m=settings.cell_m)


class RollingGrid:
    """NUS's rolling map: map-aligned cells around the shuttle, each holding its newest observation."""

    _UNKNOWN, _FREE, _OBSTACLE = -1, 0, 1

    def __init__(self, settings: NusCostMapSettings) -> None:
        self.settings = settings
        self.size = math.ceil(2.0 * settings.half_extent_m / settings.cell_m)
        self.state = np.full((self.size, self.size), self._UNKNOWN, dtype=np.int8)  # [row = y, col = x]
        self.corner: tuple[int, int] | None = None  # map cell index (x, y) of cell (0, 0)

    def roll(self, x_m: float, y_m: float) -> None:
        """Recentre on (x, y), keeping the cells both windows hold; the others start unknown."""
        cell, half = self.settings.cell_m, self.size // 2
        corner = (math.floor(x_m / cell) - half, math.floor(y_m / cell) - half)
        if self.corner is not None and corner != self.corner:
            dx, dy = corner[0] - self.corner[0], corner[1] - self.corner[1]
            old, n = self.state, self.size
            self.state = np.full_like(old, self._UNKNOWN)
            if abs(dx) < n and abs(dy) < n:
                self.state[max(0, -dy) : n - max(0, dy), max(0, -dx) : n - max(0, dx)] = old[
                    max(0, dy) : n - max(0, -dy), max(0, dx) : n - max(0, -dx)
                ]
        self.corner = corner

    def observe(self, map_xyz_m: np.ndarray) -> None:
        """Put one frame's map-frame points in: each observed cell takes this frame's verdict."""
        assert self.corner is not None, "roll() first"
        cell, half_m = self.settings.cell_m, self.size * self.settings.cell_m / 2.0
        # GEM's height map is centred on its origin: give it the points relative to the window's centre.
        centre = np.array([self.corner[0] * cell + half_m, self.corner[1] * cell + half_m, 0.0])
        config = dataclasses.replace(self.settings.height_map_config(), half_extent_m=half_m)
        heights = height_map(map_xyz_m - centre, config)
        observed = heights.observed
        assert observed is not None
        # HeightMap is indexed [ix, iy]; the state's rows are y.
        frame = np.where(heights.occupied, self._OBSTACLE, self._FREE).astype(np.int8).T
        seen = observed.T
        self.state[seen] = frame[seen]

    def cost(self) -> CostGrid:
        """The byte cost map of what the grid holds."""
        assert self.corner is not None, "roll() first"
        cell = self.settings.cell_m
        occupied, observed = self.state == self._OBSTACLE, self.state != self._UNKNOWN
        return cost_grid(occupied, observed, self.corner[0] * cell, self.corner[1] * cell, self.settings)


@dataclass(slots=True)
class NusSpeedStats:
    """Counters for the run's report."""

    frames: int = 0
    frames_unplaced: int = 0
    """Frames left out for want of a valid pose estimate at their stamp."""
    steps: int = 0
    steps_cost_bound: int = 0
    """Control steps where the cost map's speed was below the stack's own cap and the steering speed."""
    max_mean_cost: float = 0.0


class NusSpeedCap:
    """NUS's rolling cost map, updated by each processed rig frame, and the speed rule it feeds."""

    def __init__(self, settings: NusSpeedSettings, geometry: VehicleGeometry) -> None:
        self.settings = settings
        # The footprint is the shuttle's width, projected from its front bumper.
        self.rule = NusSpeedConfig(
            steer_decay_per_rad=settings.steer_decay_per_rad,
            lookahead_m=settings.lookahead_m,
            footprint_width_m=geometry.width_m,
            unknown_is_lethal=settings.unknown_is_lethal,
        )
        self.bumper = SE2(geometry.front_from_rear_axle_m, 0.0, 0.0)
        self.rolling = RollingGrid(settings.cost_map)
        self.grid: CostGrid | None = None
        self.mean_cost = 0.0
        """The last frame's normalised mean cost under the footprint (0 before the first frame)."""
        self.stats = NusSpeedStats()

    def update(self, result: LidarPipelineResult, estimate: Callable[[Stamp], LocalizationEstimate]) -> None:
        """Roll the map to the pose at the frame's stamp, put the frame in, and cost the footprint ahead.

        Args:
            result: the raw chain's frame (base frame at ``result.cloud.stamp``).
            estimate: the stack's pose estimate at a stamp.
        """
        self.stats.frames += 1
        est = estimate(result.cloud.stamp)
        if not est.valid:
            self.stats.frames_unplaced += 1
            return
        pose = est.map_from_base
        self.rolling.roll(pose.x_m, pose.y_m)
        keep = ~np.asarray(result.noise, dtype=bool)
        xyz = np.asarray(result.cloud.points[keep, :3], dtype=np.float64)
        xyz = np.column_stack([pose.apply_points(xyz[:, :2]), xyz[:, 2]])
        self.rolling.observe(xyz)
        self.grid = self.rolling.cost()
        self.mean_cost = footprint_mean_cost(self.grid, pose.compose(self.bumper), self.rule)
        self.stats.max_mean_cost = max(self.stats.max_mean_cost, self.mean_cost)

    def cap_mps(self, cap_mps: float, steer_front_rad: float, steer_rear_rad: float) -> float:
        """min(cap, steering-angle safe speed, cost-map safe speed), with v_max = ``cap_mps``."""
        self.stats.steps += 1
        if not cap_mps > 0.0:
            return cap_mps
        # Both axles steer: the front-steer angle of the same curvature (tan f - tan r) / wheelbase.
        steer_rad = math.atan(math.tan(steer_front_rad) - math.tan(steer_rear_rad))
        rule = dataclasses.replace(self.rule, max_speed_mps=cap_mps)
        v_steer = steering_safe_speed_mps(steer_rad, rule)
        v_cost = cost_safe_speed_mps(self.mean_cost, rule)
        if v_cost < v_steer:
            self.stats.steps_cost_bound += 1
        return min(v_steer, v_cost, cap_mps)

    def counters(self) -> dict[str, int]:
        """The stack report's counters of this option."""
        st = self.stats
        return {
            "nus_speed_frames": st.frames,
            "nus_speed_frames_unplaced": st.frames_unplaced,
            "nus_speed_steps": st.steps,
            "nus_speed_steps_cost_bound": st.steps_cost_bound,
        }
