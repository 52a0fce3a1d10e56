"""NUS's speed rule: min(steering-angle safe speed, cost-map safe speed)."""

import math

import numpy as np
import pytest

from lastmile.control.nus_speed import (
    CostGrid,
    NusSpeedConfig,
    footprint_mean_cost,
    nus_speed_setpoint_mps,
    steering_safe_speed_mps,
)
from lastmile.core.errors import MessageError
from lastmile.core.geometry import SE2

C = NusSpeedConfig()


def _grid(fill: int = 0) -> CostGrid:
    # NUS's 50 m x 50 m rolling map of 0.2 m cells, centred on the vehicle at the origin.
    return CostGrid(
        cost=np.full((250, 250), fill, dtype=np.uint8), origin_x_m=-25.0, origin_y_m=-25.0, cell_m=0.2
    )


def test_steering_speed_falls_exponentially_with_the_wheel_angle():
    assert steering_safe_speed_mps(0.0, C) == C.max_speed_mps
    assert steering_safe_speed_mps(-0.55, C) == pytest.approx(C.max_speed_mps * math.exp(-2.0 * 0.55))


def test_free_ground_leaves_the_steering_speed_and_an_obstacle_ahead_lowers_it():
    pose = SE2(0.0, 0.0, 0.0)
    free = _grid()
    assert nus_speed_setpoint_mps(0.1, free, pose, C) == pytest.approx(steering_safe_speed_mps(0.1, C))
    blocked = _grid()
    blocked.cost[120:130, 135:140] = 254  # 2-3 m ahead, across the footprint
    v = nus_speed_setpoint_mps(0.0, blocked, pose, C)
    assert v < 0.9 * C.max_speed_mps
    # The same obstacle behind the vehicle does not count.
    assert nus_speed_setpoint_mps(0.0, blocked, SE2(0.0, 0.0, math.pi), C) == C.max_speed_mps


def test_unknown_cells_are_lethal_or_skipped_as_configured():
    pose = SE2(0.0, 0.0, 0.0)
    unknown = _grid(255)
    assert footprint_mean_cost(unknown, pose, C) == 1.0
    assert footprint_mean_cost(unknown, pose, NusSpeedConfig(unknown_is_lethal=False)) == 0.0


def test_grid_must_be_bytes():
    with pytest.raises(MessageError, match="uint8"):
        CostGrid(cost=np.zeros((3, 3)), origin_x_m=0.0, origin_y_m=0.0, cell_m=0.2)
