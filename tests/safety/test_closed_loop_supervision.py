"""The vehicle's safety in the real closed loop: silent in a healthy run; a dead radar stops the shuttle."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.safety_messages import (
    FailSafeLevel,
    MalfunctionKind,
    MalfunctionSignal,
    MrmKind,
    SafetyDirective,
)
from lastmile.core.sensor_frames import RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
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


def test_a_minimal_risk_manoeuvre_pulls_over_to_the_curb_where_the_map_allows() -> None:
    """Visibility below the ODD (not a pull-over blocker) at 12 s: the shuttle is at ~5.5 m/s on a
    road with a curb, so the manoeuvre pulls over, and the shuttle ends at the curb, not in the lane."""
    scenario = dataclasses.replace(default_service(seed=0), minutes=0.75)
    loop = build_closed_loop(scenario, RADAR)
    reliability = loop.safety.supervisor.reliability
    evaluate = reliability.evaluate
    fog_us = 12_000_000

    def with_fog(now_us: int) -> tuple[MalfunctionSignal, ...]:
        signals = evaluate(now_us)
        if now_us < fog_us:
            return signals
        fog = MalfunctionSignal(
            stamp=Stamp(now_us),
            source="odd",
            kind=MalfunctionKind.WEATHER_VISIBILITY,
            level=FailSafeLevel.MINIMAL_RISK_MANOEUVRE,
            reason="visibility 20 m < 40 m (injected)",
        )
        return (*signals, fog)

    reliability.evaluate = with_fog  # type: ignore[method-assign]
    # No safety driver on board: the takeover the manoeuvre asks for is not taken (the simulator's
    # driver would hold the brake at once), so what is tested is the manoeuvre itself.
    loop.world.operator.step = lambda *args: None  # type: ignore[method-assign]
    directives, speeds = [], []
    for record in loop.ticks(round(45.0 * 1e6 / TICK_US)):
        directives.append(record.verdict.directive)
        speeds.append(loop.world.ego_state.speed_mps)
    first = next(i for i, d in enumerate(directives) if d.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE)
    assert directives[first].mrm == MrmKind.PULL_OVER
    assert speeds[first] > 4.0 and max(speeds[-100:]) < 0.05  # it was driving, and it stopped
    layers = loop.software.layers  # type: ignore[attr-defined]
    ego = loop.world.ego_state
    geometry = VehicleGeometry()
    # Both axles at the curb: the body's right side within 0.3 m of it, parallel to it.
    for along_m in (0.0, geometry.wheelbase_m):
        x = ego.x_m + along_m * math.cos(ego.yaw_rad)
        y = ego.y_m + along_m * math.sin(ego.yaw_rad)
        f = layers.centerline.project(x, y)
        curb_d = float(layers.curb_right_d_m[layers.record_indices(np.array([f.s_m]))[0]])
        gap = f.d_m - geometry.width_m / 2.0 - curb_d
        assert 0.0 < gap <= 0.3, (along_m, gap, f.d_m, curb_d)
        assert f.d_m < -0.5  # out of the lane's middle, not stopped in it
