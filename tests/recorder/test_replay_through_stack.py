"""A recording played back through a fresh stack reproduces the recorded commands exactly."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from lastmile.core.stamp import Stamp
from lastmile.recorder.black_box import BlackBox, BlackBoxConfig
from lastmile.recorder.mcap_codec import encode_message
from lastmile.recorder.replay import read_recording
from lastmile.runner.closed_loop import TICK_US, build_closed_loop
from lastmile.sim.scenario import default_service

pytestmark = pytest.mark.closed_loop


def test_recorded_frames_replayed_through_a_fresh_stack_give_the_recorded_commands(tmp_path: Path) -> None:
    scenario = dataclasses.replace(default_service(seed=3), minutes=12.0 / 60.0)
    _, sim, stack = build_closed_loop(scenario, "radar_tracking")
    bb = BlackBox(BlackBoxConfig(out_dir=tmp_path))
    for tick in range(round(12e6 / TICK_US)):  # shorter than the window: the recording starts at t = 0
        now = Stamp(tick * TICK_US)
        sim.advance_world(tick)
        frames = sim.sensor_frames(tick)
        out = stack.tick(now, frames)
        bb.record_frames(now, frames)
        bb.record_output(now, out)
        sim.apply_command(out.command)
        sim.referee(out.takeover_request)
    path = bb.trigger("manual", now, "replay test").result(timeout=60)
    bb.close()
    rec = read_recording(path)
    recorded = rec.on("/stack/command")
    assert rec.span_us[0] == 0 and len(recorded) == round(12e6 / TICK_US)
    assert max(abs(c.accel_mps2) for c in recorded) > 0.1  # the shuttle did something worth replaying

    _, _, fresh = build_closed_loop(scenario, "radar_tracking")
    replayed = []
    for now, frames in rec.ticks(TICK_US):
        out = fresh.tick(now, frames)
        assert out.command is not None
        replayed.append(out.command)
    assert [encode_message(c) for c in replayed] == [encode_message(c) for c in recorded]
