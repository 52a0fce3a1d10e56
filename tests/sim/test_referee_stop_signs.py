"""The referee flags rolling through a two-way stop's line (a stop sign's ref_line).

On the example town with the all-way stop's westbound line on Main Street (x = 10, lane centre
y = 1.75) made a stop sign's line of a two-way stop instead.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.model import HDMap
from lastmile.hdmap.service_route import load_route
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation

ROUTE = Path(__file__).resolve().parents[2] / "examples" / "routes" / "town_block_loop.toml"
DT_S = 0.01
WEST_X0, WEST_Y, LINE_X = 40.0, 1.75, 10.0
FRONT_M = VehicleGeometry().front_from_rear_axle_m


@pytest.fixture(scope="module")
def service():
    return load_route(ROUTE)


def _two_way(hdmap: HDMap) -> HDMap:
    def westbound(line: np.ndarray) -> bool:
        mid = np.asarray(line, dtype=float).mean(axis=0)
        return abs(mid[0] - LINE_X) < 0.5 and mid[1] > 0.0

    lines = tuple(
        dataclasses.replace(sl, all_way_stop_id=None, stop_sign_id=1) if westbound(sl.line) else sl
        for sl in hdmap.stop_lines
    )
    assert sum(sl.stop_sign_id is not None for sl in lines) == 1
    return dataclasses.replace(hdmap, stop_lines=lines)


def _drive(service, speeds: list[float]) -> list[str]:
    """The rear axle westbound from x = 40 at ``speeds[k]`` in tick k; the rules broken."""
    sim = Simulation(
        Scenario(name="stop_sign", minutes=1.0),
        _two_way(service.hdmap),
        service.polyline,
        VehicleGeometry(),
        10_000,
        map_speed_limits=True,
        unmapped_speed_limit_mps=service.unmapped_speed_limit_mps,
    )
    sim.world.agents = []
    s = sim.world.ego.state
    s.x_m, s.y_m, s.yaw_rad = WEST_X0, WEST_Y, math.pi
    for k, v in enumerate(speeds):
        sim.world.t_s = k * DT_S
        s.speed_mps = v
        s.x_m -= v * DT_S
        sim.judge.step()
    return [str(d.get("rule")) for _, _, d in sim.judge.events if d.get("rule")]


def test_rolling_through_a_stop_sign_line_is_a_violation(service) -> None:
    assert "stop_sign" in _drive(service, [4.0] * 1000)  # 40 m at 4 m/s, never stopping
    assert "stop_sign" in _drive(service, [4.0] * 400 + [1.0] * 1500)  # slowed to 1 m/s, never stopped


def test_a_full_stop_at_the_line_then_going_is_legal(service) -> None:
    approach = [4.0] * int((WEST_X0 - LINE_X - FRONT_M - 1.0) / 4.0 / DT_S)
    assert _drive(service, approach + [0.0] * 100 + [3.0] * 500) == []
