"""NUS's rolling cost map and speed rule as a stack option (``[stack.nus_speed]``, issue #20), on
synthetic frames: obstacle cells 254, costmap_2d's exponential fall-off around them, 255 where no
point fell; the cap near full on an empty road, lowered in front of a box and by the wheel angle."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import cast

import numpy as np
import pytest

from lastmile.control.lateral import LateralControllerName
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import LocalizationEstimate
from lastmile.perception.pipeline import LidarPipelineResult
from lastmile.runner.run_config import load_run_config
from lastmile.stack.nus_speed_cap import (
    NusCostMapSettings,
    NusSpeedCap,
    NusSpeedSettings,
    RollingGrid,
    cost_grid,
)
from lastmile.stack.stack_settings import StackSettings

CELL_M = 0.2


def _ground(x0_m: float, x1_m: float, y0_m: float, y1_m: float) -> np.ndarray:
    """Flat ground points (z = 0), three a cell each way: every cell is hit whatever the grid's yaw."""
    step = CELL_M / 3
    xs = np.arange(x0_m + step / 2, x1_m, step)
    ys = np.arange(y0_m + step / 2, y1_m, step)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])


def _box(x_m: float, y0_m: float, y1_m: float) -> np.ndarray:
    """A 1 m tall face across y0..y1 at x: each of its cells spreads from 0 to 1 m."""
    ys = np.arange(y0_m + CELL_M / 6, y1_m, CELL_M / 3)
    lo = np.column_stack([np.full(ys.size, x_m), ys, np.zeros(ys.size)])
    hi = lo + np.array([0.0, 0.0, 1.0])
    return np.vstack([lo, hi])


def _frame(xyz_m: np.ndarray, stamp_us: int = 0) -> LidarPipelineResult:
    points = np.zeros((len(xyz_m), 6), dtype=np.float32)
    points[:, :3] = xyz_m
    cloud = SimpleNamespace(points=points, stamp=Stamp(stamp_us))
    return cast(LidarPipelineResult, SimpleNamespace(cloud=cloud, noise=np.zeros(len(xyz_m), dtype=bool)))


def _at(pose: SE2) -> object:
    est = SimpleNamespace(valid=True, map_from_base=pose)
    return lambda _stamp: cast(LocalizationEstimate, est)


def test_the_cost_map_has_nus_bytes_and_costmap_2d_decay() -> None:
    settings = NusCostMapSettings()
    occupied = np.zeros((20, 20), dtype=bool)
    observed = np.ones((20, 20), dtype=bool)
    occupied[10, 10] = True
    observed[:, 15:] = False  # never seen
    occupied[10, 17] = True  # an obstacle in it is still an obstacle
    grid = cost_grid(occupied, observed, -2.0, -2.0, settings)
    c = grid.cost
    assert c.dtype == np.uint8 and c[10, 10] == 254 and c[10, 17] == 254
    # 252 exp(-10 d): one cell (0.2 m) 34, two cells 5, the diagonal 0.28 m 15; beyond 0.55 m free.
    assert c[10, 11] == round(252 * math.exp(-2.0)) == 34
    assert c[10, 12] == round(252 * math.exp(-4.0)) == 5
    assert c[11, 11] == round(252 * math.exp(-10 * math.hypot(0.2, 0.2)))
    assert c[10, 13] == 0 and c[0, 0] == 0
    # Inflation does not make an unknown cell known (costmap_2d's default).
    assert c[10, 16] == 255 and c[0, 19] == 255
    assert (grid.origin_x_m, grid.origin_y_m, grid.cell_m) == (-2.0, -2.0, 0.2)


def test_the_rolling_grid_keeps_what_it_saw_and_forgets_what_it_rolls_off() -> None:
    rolling = RollingGrid(NusCostMapSettings(half_extent_m=5.0))
    rolling.roll(0.0, 0.0)
    rolling.observe(np.vstack([_ground(0.0, 4.0, -1.0, 1.0), _box(3.05, -0.4, 0.4)]))
    grid = rolling.cost()

    def cost_at(x_m: float, y_m: float) -> int:
        g = rolling.cost()
        return int(g.cost[int((y_m - g.origin_y_m) // g.cell_m), int((x_m - g.origin_x_m) // g.cell_m)])

    assert cost_at(3.1, 0.1) == 254 and cost_at(1.1, 0.1) == 0 and cost_at(-2.1, 0.1) == 255
    assert grid.cost.shape == (50, 50)
    # Two metres on: the same map cells hold the same bytes; what rolled in is unknown.
    rolling.roll(2.0, 0.0)
    assert cost_at(3.1, 0.1) == 254 and cost_at(1.1, 0.1) == 0 and cost_at(6.9, 0.1) == 255
    # A frame that sees ground where the box stood clears it; a frame that sees nothing there leaves it.
    rolling.observe(_ground(5.0, 6.0, -1.0, 1.0))
    assert cost_at(3.1, 0.1) == 254 and cost_at(5.1, 0.1) == 0
    rolling.observe(_ground(2.8, 3.4, -1.0, 1.0))
    assert cost_at(3.1, 0.1) == 0
    # Rolled further than the window: everything is unknown again.
    rolling.roll(40.0, 0.0)
    assert (rolling.cost().cost == 255).all()


def _cap(xyz_base_m: np.ndarray, steer_front_rad: float = 0.0, **kw: object) -> tuple[float, NusSpeedCap]:
    geometry = VehicleGeometry()
    cap = NusSpeedCap(NusSpeedSettings(**kw), geometry)  # type: ignore[arg-type]
    pose = SE2(10.0, -3.0, 0.7)  # the map frame is not the base frame
    cap.update(_frame(xyz_base_m), _at(pose))  # type: ignore[arg-type]
    return cap.cap_mps(5.0, steer_front_rad, 0.0), cap


def test_the_cap_is_near_full_on_an_empty_road_and_lowered_before_a_box() -> None:
    front_m = VehicleGeometry().front_from_rear_axle_m
    road = _ground(-1.0, front_m + 12.0, -1.6, 1.6)  # a 3.2 m lane seen all along
    v_clear, clear = _cap(road)
    assert clear.mean_cost == 0.0 and v_clear == pytest.approx(5.0)
    # A 1.2 m wide box 2 m ahead of the bumper, across the lane's middle, hiding the road behind it.
    x_box = front_m + 2.05
    behind = (road[:, 0] > x_box) & (np.abs(road[:, 1]) < 0.6)
    v_box, boxed = _cap(np.vstack([road[~behind], _box(x_box, -0.6, 0.6)]))
    assert 0.3 < boxed.mean_cost < 0.7 and v_box == pytest.approx(5.0 * (1.0 - boxed.mean_cost))
    # Its face alone (the road behind it seen, as it would be by a taller LiDAR) weighs far less.
    _, face = _cap(np.vstack([road, _box(x_box, -0.6, 0.6)]))
    assert 0.0 < face.mean_cost < 0.1
    assert v_box < 0.9 * v_clear
    # The wheel angle's own safe speed: v_max exp(-2 |delta|).
    v_steer, _ = _cap(road, steer_front_rad=0.2)
    assert v_steer == pytest.approx(5.0 * math.exp(-0.4))
    # Nothing seen ahead: unknown counts as lethal (the default) and stops the shuttle, or is left out.
    v_blind, blind = _cap(_ground(-1.0, front_m - 0.5, -1.6, 1.6))
    assert blind.mean_cost == 1.0 and v_blind == 0.0
    v_open, _ = _cap(_ground(-1.0, front_m - 0.5, -1.6, 1.6), unknown_is_lethal=False)
    assert v_open == pytest.approx(5.0)
    counters = boxed.counters()
    assert counters["nus_speed_frames"] == 1 and counters["nus_speed_steps_cost_bound"] == 1


def test_it_needs_the_lidars_and_positive_constants() -> None:
    with pytest.raises(ConfigError, match=r"stack.nus_speed: expected perception = 'lidar_camera_radar'"):
        StackSettings(perception=PerceptionMode.RADAR_TRACKING, nus_speed=NusSpeedSettings())
    with pytest.raises(ConfigError, match=r"stack.nus_speed.lookahead_m: expected a positive number"):
        NusSpeedSettings(lookahead_m=0.0)
    with pytest.raises(ConfigError, match=r"stack.nus_speed.cost_map.cell_m: expected a positive number"):
        NusCostMapSettings(cell_m=-0.2)


def test_the_example_configuration_selects_nus_pure_pursuit_and_the_rule(tmp_path: Path) -> None:
    config = load_run_config(Path(__file__).parents[2] / "examples" / "configs" / "nus_golf_car.toml")
    assert config.stack.lateral_controller is LateralControllerName.NUS_PURE_PURSUIT
    assert config.stack.nus_speed == NusSpeedSettings()  # the file spells out the defaults
    bad = tmp_path / "bad.toml"
    bad.write_text("[stack.nus_speed.cost_map]\ncell_size = 0.2\n")
    with pytest.raises(ConfigError, match="cell_size"):
        load_run_config(bad)
