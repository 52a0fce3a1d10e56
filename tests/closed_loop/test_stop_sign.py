"""A two-way stop in the loop, radar tracking: the shuttle stands its full stop at the line, then goes.

The example town with its all-way stop's westbound line on Main Street (x = 10, lane centre y = 1.75)
made a stop sign's line instead (the map as the stack and the simulator both load it). The shuttle
starts at route s 540, 24 m before it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import lastmile.runner.closed_loop as closed_loop
from lastmile.core.vehicle_messages import StopReason
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig
from lastmile.hdmap.service_route import ServiceRoute, load_route
from lastmile.sim.scenario import MapSpec, Scenario
from tests.closed_loop.harness import steps

pytestmark = pytest.mark.closed_loop
ROUTE = "examples/routes/town_block_loop.toml"
LINE_X = 10.0
FULL_STOP_S = TrafficLightRuleConfig().full_stop_s


def _two_way_stop(spec: MapSpec) -> ServiceRoute:
    service = load_route(spec.route)

    def westbound(line: np.ndarray) -> bool:
        mid = np.asarray(line, dtype=float).mean(axis=0)
        return abs(mid[0] - LINE_X) < 0.5 and mid[1] > 0.0

    lines = tuple(
        dataclasses.replace(sl, all_way_stop_id=None, stop_sign_id=1) if westbound(sl.line) else sl
        for sl in service.hdmap.stop_lines
    )
    return dataclasses.replace(service, hdmap=dataclasses.replace(service.hdmap, stop_lines=lines))


def test_the_shuttle_stands_its_full_stop_at_the_line_then_crosses(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(closed_loop, "load_world_map", _two_way_stop)
    scenario = Scenario(
        name="stop_sign", minutes=0.4, start_route_s_m=540.0, map=MapSpec(name="route", route=ROUTE)
    )
    stood_s, prev_t_s = 0.0, 0.0
    crossed_after_s = None
    reasons = set()
    for step in steps(scenario):
        ego = step.sim.world.ego
        front_x = ego.state.x_m - ego.geometry.front_from_rear_axle_m  # westbound: the front is at smaller x
        d = step.out.decision
        if d is not None and d.stop_reason is StopReason.STOP_LINE:
            reasons.add(d.reason)
        if LINE_X < front_x < LINE_X + 4.0 and ego.state.speed_mps < 0.1:
            stood_s += step.t_s - prev_t_s  # standing within 4 m of the line (the referee's full stop)
        prev_t_s = step.t_s
        if crossed_after_s is None and front_x < LINE_X:
            crossed_after_s = stood_s
    assert any("stop sign" in r for r in reasons), reasons
    assert crossed_after_s is not None, "never crossed the line"
    assert crossed_after_s >= FULL_STOP_S
    violations = [e for e in step.sim.judge.events if e[1].value == "rule_violation"]
    assert violations == []
