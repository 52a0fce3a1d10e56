"""Runs a scenario tick by tick with the stack, giving tests the simulator's truth beside the stack's output.

Only tests read ground truth here (to judge the stack); the stack itself still gets sensor frames only.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import StackOutput
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation
from lastmile.stack.shuttle_stack import ShuttleStack, StackConfig

TICK_US = 10_000


@dataclass
class Step:
    t_s: float
    sim: Simulation
    out: StackOutput


def steps(scenario: Scenario, until: Callable[[Step], bool] | None = None) -> Iterator[Step]:
    hdmap = load_campus_map()
    loop = campus_shuttle_loop(hdmap)
    geometry = VehicleGeometry()
    sim = Simulation(scenario, hdmap, route_polyline(hdmap, loop, closed=True), geometry, TICK_US)
    stack = ShuttleStack(
        SLayerDatabase.build(hdmap, loop, step_m=1.0, closed=True),
        geometry,
        StackConfig(tick_us=TICK_US, radar_mounts=sim.radar_mounts, serve_all_stops=scenario.serve_all_stops),
    )
    for tick in range(round(scenario.minutes * 60e6 / TICK_US)):
        sim.advance_world(tick)
        out = stack.tick(Stamp(tick * TICK_US), sim.sensor_frames(tick))
        sim.apply_command(out.command)
        sim.referee(out.takeover_request)
        step = Step(tick * TICK_US / 1e6, sim, out)
        yield step
        if until is not None and until(step):
            return
