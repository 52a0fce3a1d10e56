"""The referee judges the rules a route map states, on the example town: the stop lines of an all-way
stop whose lanelets do not reference the rule (only the rule lists them), and the red of a signalised
junction whose crossing approaches run the other phase."""

from __future__ import annotations

import math
from pathlib import Path

from lastmile.core.traffic_light_messages import LightState
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.service_route import load_route
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation

ROUTE = Path(__file__).resolve().parents[2] / "examples" / "routes" / "town_block_loop.toml"
DT_S = 0.01


def _drive(
    x: float, y: float, yaw: float, speeds: list[float], t0_s: float = 0.0
) -> tuple[Simulation, list[str]]:
    """The shuttle's rear axle from (x, y) along ``yaw``, at ``speeds[k]`` in tick k; the rules broken."""
    service = load_route(ROUTE)
    sim = Simulation(
        Scenario(name="rules", minutes=1.0),
        service.hdmap,
        service.polyline,
        VehicleGeometry(),
        10_000,
        map_speed_limits=True,
        unmapped_speed_limit_mps=service.unmapped_speed_limit_mps,
    )
    sim.world.agents = []
    s = sim.world.ego.state
    s.x_m, s.y_m, s.yaw_rad = x, y, yaw
    for k, v in enumerate(speeds):
        sim.world.t_s = t0_s + k * DT_S
        s.speed_mps = v
        s.x_m += v * DT_S * math.cos(yaw)
        s.y_m += v * DT_S * math.sin(yaw)
        sim.judge.step()
    return sim, [str(d.get("rule")) for _, kind, d in sim.judge.events if d.get("rule")]


# Main Street westbound (lane centre y = 1.75) towards the all-way stop at (0, 0): its line is at x = 10.
WEST_X0, WEST_Y = 40.0, 1.75


def test_running_a_stop_line_only_the_rule_lists_is_a_violation() -> None:
    _, rules = _drive(WEST_X0, WEST_Y, math.pi, [4.0] * 1000)  # 40 m at 4 m/s, never stopping
    assert "stop_line" in rules


def test_stopping_at_that_line_then_going_is_legal() -> None:
    # The front bumper is ~3.9 m ahead of the rear axle: stop with it 1 m before the line, wait, go.
    approach = [4.0] * int((WEST_X0 - 10.0 - 3.9 - 1.0) / 4.0 / DT_S)
    sim, rules = _drive(WEST_X0, WEST_Y, math.pi, approach + [0.0] * 200 + [3.0] * 500)
    assert rules == []
    entries = [d for _, kind, d in sim.judge.events if kind.value == "intersection_entry"]
    assert len(entries) == 1 and entries[0]["order_ok"]


def _signal_state_for_heading(sim: Simulation, heading: float, t_s: float) -> LightState:
    hdmap = sim.world.hdmap
    for sig in hdmap.signals:
        centre = hdmap.lanelets[sig.lanelet_id].centerline
        if math.cos(centre.heading_at(centre.length_m) - heading) > 0.9:
            return sim.signals.state(sig.id, t_s)
    raise AssertionError("no signal for that heading")


def test_a_red_at_the_signalised_junction_is_judged_and_the_crossing_green_is_not() -> None:
    # East Avenue southbound (lane centre x = 198.25) towards the signal at (200, 0): its line is at y = 10.
    south = -math.pi / 2
    probe, _ = _drive(198.25, 40.0, south, [])
    red_at = next(
        t for t in range(0, 120) if _signal_state_for_heading(probe, south, float(t)) is LightState.RED
    )
    # Red for the whole 8 s run over the line? Start where it has just turned red.
    _, rules = _drive(198.25, 40.0, south, [4.0] * 800, t0_s=float(red_at))
    assert "red_light" in rules
    # Main Street eastbound (lane centre y = -1.75) towards the same junction, line at x = 190, at the same
    # time: its approach crosses East Avenue's, so it shows green then.
    east = 0.0
    assert _signal_state_for_heading(probe, east, float(red_at) + 5.0) is LightState.GREEN
    _, rules = _drive(160.0, -1.75, east, [4.0] * 800, t0_s=float(red_at) + 2.0)
    assert "red_light" not in rules
