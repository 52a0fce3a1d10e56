"""With the default raw-sensor perception, the stack's own supervisor watches the LiDARs and cameras."""

from __future__ import annotations

import dataclasses

from lastmile.core.safety_messages import FailSafeLevel
from lastmile.core.sensor_frames import LidarSweep
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.sim.scenario import default_service
from lastmile.stack.shuttle_stack import ShuttleStack
from tests.closed_loop.harness import CutSensor


def test_a_dead_front_lidar_is_reported_within_a_period_and_the_shuttle_stops() -> None:
    scenario = dataclasses.replace(default_service(seed=0), minutes=22.0 / 60.0)
    dies_us = 8_000_000
    # The front unit's cable is cut at 8 s: no more sweeps from it. Default perception: raw sensors.
    loop = build_closed_loop(scenario, callbacks=(CutSensor(LidarSweep, "front", dies_us),))
    stack = loop.software
    assert isinstance(stack, ShuttleStack)
    first_seen_us = None
    levels = []
    for record in loop.ticks(round(22e6 / loop.tick_us)):
        d = record.verdict.directive
        if any("lidar_front" in r for r in d.reasons) and first_seen_us is None:
            first_seen_us = int(record.now)
        levels.append(d.level)
    assert first_seen_us is not None, "the dead front LiDAR was never reported"
    # Its last sweep was due 8.0 s (+ 120 ms delivery); silence is called within one period + margin.
    assert first_seen_us - dies_us <= 300_000, first_seen_us - dies_us
    assert max(levels) >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE
    assert loop.world.ego_state.speed_mps < 0.05  # the minimal risk manoeuvre brought it to a stop
    assert stack.raw is not None and stack.raw.stats.incomplete_frames > 0  # side units kept working
