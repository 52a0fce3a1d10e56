"""NUS's speed rule (its IV-B): the lower of a steering-angle safe speed and a cost-map safe speed.

"First, an exponential function is used to calculate the safe speed given the steering angle of the
golf car. Then, from the normalized average cost along the projection of the golf car within a fix
distance, another safe speed is obtained. Between these 2 values, the minimum one is chosen." The cost
map is NUS's rolling grid (0.2 m cells, one byte each: 254 an obstacle, costs falling off exponentially
around it, 255 unknown). NUS publishes the rule's form, not its constants; the defaults are ours and
named below. The stack runs it as ``[stack.nus_speed]`` (:mod:`lastmile.stack.nus_speed_cap`, which
builds the cost map from the LiDAR frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2

#: NUS's cost values: an obstacle cell and a cell never observed.
LETHAL_COST = 254
UNKNOWN_COST = 255


@dataclass(frozen=True, slots=True, kw_only=True)
class NusSpeedConfig:
    """Constants of the rule.

    Attributes:
        max_speed_mps: the speed on a straight, empty road (NUS's golf car: 2 m/s).
        steer_decay_per_rad: v_steer = v_max exp(-k |delta|); 2 /rad gives a third of v_max at full lock
            (0.55 rad).
        lookahead_m: the "fix distance" of the footprint projected ahead.
        footprint_width_m: width of the projected footprint.
        unknown_is_lethal: count never-observed cells as obstacles (NUS's conservative choice) or skip them.
    """

    max_speed_mps: float = 2.0
    steer_decay_per_rad: float = 2.0
    lookahead_m: float = 6.0
    footprint_width_m: float = 1.4
    unknown_is_lethal: bool = True

    def __post_init__(self) -> None:
        for name in ("max_speed_mps", "steer_decay_per_rad", "lookahead_m", "footprint_width_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"NusSpeedConfig.{name}: expected a positive number, got {value}")


@dataclass(frozen=True, slots=True, kw_only=True)
class CostGrid:
    """A rolling cost map.

    Attributes:
        cost: (H, W) uint8, row = y index, column = x index; 254 obstacle, 255 unknown.
        origin_x_m, origin_y_m: map position of the corner of cell (0, 0).
        cell_m: cell size (NUS: 0.2 m).
    """

    cost: np.ndarray
    origin_x_m: float
    origin_y_m: float
    cell_m: float

    def __post_init__(self) -> None:
        if self.cost.ndim != 2 or self.cost.dtype != np.uint8:
            raise MessageError(
                f"CostGrid.cost: expected (H, W) uint8, got {self.cost.shape} {self.cost.dtype}"
            )
        if not self.cell_m > 0.0:
            raise MessageError(f"CostGrid.cell_m: expected a positive cell size, got {self.cell_m}")


def steering_safe_speed_mps(steer_rad: float, c: NusSpeedConfig) -> float:
    """v_max exp(-k |delta|)."""
    return c.max_speed_mps * math.exp(-c.steer_decay_per_rad * abs(steer_rad))


def footprint_mean_cost(grid: CostGrid, pose: SE2, c: NusSpeedConfig) -> float:
    """Normalised mean cost (0 free .. 1 obstacle) of the cells under the footprint ``lookahead_m`` ahead.

    The footprint is sampled every half cell; samples outside the grid count as unknown.
    """
    step = grid.cell_m / 2.0
    along = np.arange(0.0, c.lookahead_m + 1e-9, step)
    across = np.arange(-c.footprint_width_m / 2.0, c.footprint_width_m / 2.0 + 1e-9, step)
    a, b = np.meshgrid(along, across, indexing="ij")
    cy, sy = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    x = pose.x_m + cy * a - sy * b
    y = pose.y_m + sy * a + cy * b
    col = np.floor((x - grid.origin_x_m) / grid.cell_m).astype(np.int64)
    row = np.floor((y - grid.origin_y_m) / grid.cell_m).astype(np.int64)
    h, w = grid.cost.shape
    inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
    values = np.full(row.shape, UNKNOWN_COST, dtype=np.int64)
    values[inside] = grid.cost[row[inside], col[inside]]
    unknown = values == UNKNOWN_COST
    if c.unknown_is_lethal:
        values[unknown] = LETHAL_COST
    elif unknown.all():
        return 0.0
    else:
        values = values[~unknown]
    return float(np.mean(np.minimum(values, LETHAL_COST)) / LETHAL_COST)


def cost_safe_speed_mps(mean_cost: float, c: NusSpeedConfig) -> float:
    """v_max (1 - normalised mean cost): full speed on free ground, stopped on an obstacle."""
    return c.max_speed_mps * (1.0 - min(max(mean_cost, 0.0), 1.0))


def nus_speed_setpoint_mps(steer_rad: float, grid: CostGrid | None, pose: SE2, c: NusSpeedConfig) -> float:
    """The rule: min(steering-angle safe speed, cost-map safe speed); no grid leaves the first alone."""
    v = steering_safe_speed_mps(steer_rad, c)
    if grid is not None:
        v = min(v, cost_safe_speed_mps(footprint_mean_cost(grid, pose, c), c))
    return v
