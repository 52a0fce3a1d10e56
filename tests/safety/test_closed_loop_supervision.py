"""The vehicle's safety in the real closed loop: silent in a healthy run; a dead radar stops the shuttle."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from lastmile.core.safety_messages import FailSafeLevel, MrmKind, SafetyDirective
from lastmile.core.sensor_frames import RadarFrame
from lastmile.recorder.black_box import BlackBoxConfig
from lastmile.recorder.replay import read_recording
from lastmile.recorder.run_log import RunMeta
from lastmile.recorder.run_log_writer import RunLogWriter
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.loop import LoopCallback, TickRecord
from lastmile.runner.loop_callbacks import BlackBoxCallback
from lastmile.sim.scenario import default_service
from tests.closed_loop.harness import RADAR, CutSensor

pytestmark = pytest.mark.closed_loop
TICK_US = RADAR.loop.tick_us


class _Watch(LoopCallback):
    """Collects the directives and true speeds; asks the black box for a dump when an MRM starts."""

    def __init__(self, box: BlackBoxCallback) -> None:
        self.box = box
        self.directives: list[SafetyDirective] = []
        self.speeds: list[float] = []

    def on_tick(self, record: TickRecord) -> None:
        d = record.verdict.directive
        if d.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE and d.since_us == record.now:
            self.box.box.trigger("manual", int(record.now), "; ".join(d.reasons))
        self.directives.append(d)


def _drive(seconds: float, out_dir: Path, radar_dies_at_s: float | None = None) -> tuple[_Watch, list[Path]]:
    scenario = dataclasses.replace(default_service(seed=0), minutes=seconds / 60.0)
    loop = build_closed_loop(scenario, RADAR)
    writer = RunLogWriter(
        RunMeta(
            seed=0,
            weather="clear",
            perception_mode="radar_tracking",
            scenario_name="t",
            map_name="m",
            tick_s=TICK_US / 1e6,
            duration_s=seconds,
        )
    )
    box = BlackBoxCallback(BlackBoxConfig(out_dir=out_dir), writer)
    watch = _Watch(box)
    cut_us = None if radar_dies_at_s is None else round(radar_dies_at_s * 1e6)
    loop.callbacks.extend([CutSensor(RadarFrame, "front", cut_us), box, watch])
    for _ in loop.ticks(round(seconds * 1e6 / TICK_US)):
        watch.speeds.append(loop.world.ego_state.speed_mps)
    return watch, box.box.dumps


def test_healthy_run_raises_no_malfunction(tmp_path: Path) -> None:
    watch, dumps = _drive(25.0, tmp_path)
    assert {d.level for d in watch.directives} == {FailSafeLevel.NONE}
    assert max(watch.speeds) > 2.0  # it did drive
    assert dumps == []


def test_dead_front_radar_triggers_a_minimal_risk_manoeuvre_that_stops_the_shuttle(tmp_path: Path) -> None:
    dies_at = 12.0
    watch, dumps = _drive(25.0, tmp_path, radar_dies_at_s=dies_at)
    directives, speeds = watch.directives, watch.speeds
    noticed = next(i for i, d in enumerate(directives) if d.level > FailSafeLevel.NONE)
    # The overdue frame is a latency fault (SPEED_LIMIT) first; the silence then escalates to an MRM.
    assert directives[noticed].level in (FailSafeLevel.SPEED_LIMIT, FailSafeLevel.MINIMAL_RISK_MANOEUVRE)
    first = next(i for i, d in enumerate(directives) if d.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE)
    assert first * TICK_US / 1e6 - dies_at <= 0.05 + 0.1  # one radar period + 100 ms
    d = directives[first]
    assert d.level == FailSafeLevel.MINIMAL_RISK_MANOEUVRE and d.mrm == MrmKind.STOP_IN_LANE
    assert any("sensor:front" in r for r in d.reasons)
    assert all(x.level == FailSafeLevel.MINIMAL_RISK_MANOEUVRE for x in directives[first:])
    assert speeds[first] > 1.0 and speeds[-1] < 0.05  # it was moving and came to a stop
    # The MRM asks for a takeover, which the referee logs: the loop's black box (MRM, takeover) and the
    # watcher (manual) trigger on the same tick, one incident: one file holding all three events.
    assert len(dumps) == 1, dumps
    rec = read_recording(dumps[0])
    triggers = [ev["trigger"] for ev in rec.events]
    assert sorted(triggers) == ["manual", "mrm", "takeover"], triggers
    assert {int(ev["time_us"]) for ev in rec.events} == {first * TICK_US}
    manual = next(ev for ev in rec.events if ev["trigger"] == "manual")
    assert "no frame" in manual["reason"]
    # Everything from the start (less than 30 s so far) to the merge time after the trigger.
    assert rec.span_us == (0, first * TICK_US + BlackBoxConfig(out_dir=tmp_path).merge_us)
