"""Runs a scenario tick by tick with the stack, giving tests the simulator's truth beside the stack's output.

Only tests read ground truth here (to judge the stack); the stack itself still gets sensor frames only.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import StackOutput
from lastmile.runner.closed_loop import TICK_US, build_closed_loop
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation


@dataclass
class Step:
    t_s: float
    sim: Simulation
    out: StackOutput


def steps(scenario: Scenario, until: Callable[[Step], bool] | None = None) -> Iterator[Step]:
    _, sim, stack = build_closed_loop(scenario, "radar_tracking")
    for tick in range(round(scenario.minutes * 60e6 / TICK_US)):
        sim.advance_world(tick)
        out = stack.tick(Stamp(tick * TICK_US), sim.sensor_frames(tick))
        sim.apply_command(out.command)
        sim.referee(out.takeover_request)
        step = Step(tick * TICK_US / 1e6, sim, out)
        yield step
        if until is not None and until(step):
            return
