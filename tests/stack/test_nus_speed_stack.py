"""NUS's speed rule in the closed loop (``[stack.nus_speed]``, issue #20): the rolling cost map fills
in as the shuttle sets off, leaves the open road at full speed, and marks a box on the lane lethal and
raises the cost ahead as the shuttle comes up to it."""

from __future__ import annotations

import dataclasses
import functools
import math

import pytest

from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.run_config import RunConfig
from lastmile.sim.scenario import Scenario, StaticObstacle
from lastmile.stack.nus_speed_cap import NusSpeedSettings
from lastmile.stack.shuttle_stack import ShuttleStack

pytestmark = pytest.mark.closed_loop

BOX_S_M = 50.0
SECONDS = 17.0


@functools.cache
def _run() -> tuple[list[tuple[float, float, float, float, int]], ShuttleStack]:
    scenario = Scenario(
        name="box_ahead", minutes=SECONDS / 60.0, static_obstacles=(StaticObstacle(route_s_m=BOX_S_M),)
    )
    base = RunConfig()
    config = dataclasses.replace(base, stack=dataclasses.replace(base.stack, nus_speed=NusSpeedSettings()))
    loop = build_closed_loop(scenario, config)
    stack = loop.software
    assert isinstance(stack, ShuttleStack) and stack.nus_speed is not None
    box = loop.world.road_users[-1]
    ego = loop.world.world.ego
    front_m = stack.geometry.front_from_rear_axle_m
    trace = []
    for record in loop.ticks(round(SECONDS * 1e6 / loop.tick_us)):
        assert record.output is not None, record.failure
        if record.tick % 10 == 0 and stack.nus_speed.grid is not None:
            st = ego.state
            # Truth for the check only: the bumper's gap to the box, and the map's byte at its centre.
            gap = math.hypot(box.x_m - st.x_m, box.y_m - st.y_m) - front_m - box.length_m / 2.0
            g = stack.nus_speed.grid
            # Cells within the box's half length of its centre (whatever the road's heading there).
            r = math.ceil((box.length_m / 2.0) / g.cell_m)
            row = math.floor((box.y_m - g.origin_y_m) / g.cell_m)
            col = math.floor((box.x_m - g.origin_x_m) / g.cell_m)
            patch = g.cost[max(row - r, 0) : max(row + r + 1, 0), max(col - r, 0) : max(col + r + 1, 0)]
            near_face = int(patch.max()) if patch.size else -1
            trace.append((record.tick / 100.0, gap, stack.nus_speed.mean_cost, st.speed_mps, near_face))
    return trace, stack


def test_the_map_fills_in_leaves_the_open_road_free_and_marks_the_box() -> None:
    trace, stack = _run()
    # Standing at the start, most of the footprint ahead is unknown (255, lethal): the rule holds the
    # shuttle back until the map has seen the road.
    assert trace[0][2] > 0.5, trace[:3]
    # On the open road the footprint is seen and free: the rule leaves the cruise speed alone.
    open_road = [(t, c, v) for t, gap, c, v, _ in trace if 15.0 < gap < 35.0]
    assert open_road and max(c for _, c, _ in open_road) < 0.03, open_road
    assert max(v for _, _, v in open_road) > 5.0, open_road
    # The box's near face is an obstacle in the map once it is in range, and the cost ahead rises
    # before it (its face and the road it hides).
    in_range = [face for _, gap, _, _, face in trace if gap < 20.0]
    assert in_range and all(face == 254 for face in in_range[-20:]), in_range[-20:]
    close = [c for _, gap, c, _, _ in trace if gap < 5.0]
    assert close and max(close) > 0.05, close
    counters = stack.report().counters
    assert counters["nus_speed_frames"] >= 10 * SECONDS - 5 and counters["nus_speed_frames_unplaced"] == 0
    assert 0 < counters["nus_speed_steps_cost_bound"] < counters["nus_speed_steps"]
