"""Runs a scenario through the loop engine, giving tests the simulator's truth beside the stack's output.

Only tests read ground truth here (to judge the stack); the stack itself still gets sensor frames only.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import SafetyVerdict, StackOutput
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.loop import LoopCallback, TickRecord
from lastmile.runner.run_config import RunConfig
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation

RADAR = RunConfig().with_perception(PerceptionMode.RADAR_TRACKING)
"""The configuration the closed-loop tests run with unless they say otherwise (radar object lists)."""


class CutSensor(LoopCallback):
    """A test probe in the loop's sense phase: from ``at_us`` on, frames of ``frame_type`` from
    ``sensor_id`` no longer arrive (the unit's cable is cut)."""

    def __init__(self, frame_type: type, sensor_id: str, at_us: int | None) -> None:
        self.frame_type, self.sensor_id, self.at_us = frame_type, sensor_id, at_us

    def on_sense(self, tick: int, now: Stamp, frames: list[SensorFrame]) -> list[SensorFrame]:
        if self.at_us is None or now < self.at_us:
            return frames
        return [
            f
            for f in frames
            if not (isinstance(f, self.frame_type) and getattr(f, "sensor_id", None) == self.sensor_id)
        ]


@dataclass
class Step:
    t_s: float
    sim: Simulation
    out: StackOutput
    verdict: SafetyVerdict
    record: TickRecord


def steps(
    scenario: Scenario,
    until: Callable[[Step], bool] | None = None,
    config: RunConfig = RADAR,
    callbacks: tuple[LoopCallback, ...] = (),
) -> Iterator[Step]:
    """The scenario's ticks as they happen; stops after the first step ``until`` accepts."""
    loop = build_closed_loop(scenario, config, callbacks)
    for record in loop.ticks(round(scenario.minutes * 60e6 / config.loop.tick_us)):
        assert record.output is not None, record.failure
        step = Step(record.t_s, loop.world, record.output, record.verdict, record)
        yield step
        if until is not None and until(step):
            return
