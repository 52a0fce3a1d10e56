"""With the default raw-sensor perception, the stack's own supervisor watches the LiDARs and cameras."""

from __future__ import annotations

import dataclasses

from lastmile.core.safety_messages import FailSafeLevel
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.runner.closed_loop import TICK_US, build_closed_loop
from lastmile.sim.scenario import default_service


def test_a_dead_front_lidar_is_reported_within_a_period_and_the_shuttle_stops() -> None:
    scenario = dataclasses.replace(default_service(seed=0), minutes=22.0 / 60.0)
    _, sim, stack = build_closed_loop(scenario)  # default: lidar_camera_radar
    dies_us = 8_000_000
    first_seen_us = None
    levels = []
    for tick in range(round(22e6 / TICK_US)):
        now = Stamp(tick * TICK_US)
        sim.advance_world(tick)
        frames = sim.sensor_frames(tick)
        if int(now) >= dies_us:  # the front unit's cable is cut: no more sweeps from it
            frames = [f for f in frames if not (isinstance(f, LidarSweep) and f.sensor_id == "front")]
        out = stack.tick(now, frames)
        sim.apply_command(out.command)
        sim.referee(out.takeover_request)
        d = out.safety
        if d is not None and any("lidar_front" in r for r in d.reasons) and first_seen_us is None:
            first_seen_us = int(now)
        levels.append(d.level if d is not None else FailSafeLevel.NONE)
    assert first_seen_us is not None, "the dead front LiDAR was never reported"
    # Its last sweep was due 8.0 s (+ 120 ms delivery); silence is called within one period + margin.
    assert first_seen_us - dies_us <= 300_000, first_seen_us - dies_us
    assert max(levels) >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE
    assert sim.world.ego.state.speed_mps < 0.05  # the minimal risk manoeuvre brought it to a stop
    assert stack.raw is not None and stack.raw.stats.incomplete_frames > 0  # side units kept working
