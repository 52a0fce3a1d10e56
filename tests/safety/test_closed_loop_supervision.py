"""The safety chain beside the real closed loop: silent in a healthy run; a dead radar stops the shuttle."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from lastmile.core.safety_messages import FailSafeLevel, MrmKind, SafetyDirective
from lastmile.core.sensor_frames import RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.recorder.black_box import BlackBox, BlackBoxConfig
from lastmile.recorder.replay import read_recording
from lastmile.runner.closed_loop import TICK_US, build_closed_loop
from lastmile.safety.failsafe import FailSafeArbiter, apply_safety_gate
from lastmile.safety.hardware_watchdog import HardwareWatchdog
from lastmile.safety.health_monitor import HealthMonitor, ModuleSpec
from lastmile.safety.reliability_config import ReliabilityConfig, SensorSpec
from lastmile.safety.reliability_monitor import ReliabilityMonitor
from lastmile.safety.supervisor import SafetySupervisor
from lastmile.sim.scenario import default_service

pytestmark = pytest.mark.closed_loop

SENSORS = (
    SensorSpec(key="gnss", rate_hz=10.0),
    SensorSpec(key="imu", rate_hz=50.0, frozen_after=5),
    SensorSpec(key="odom", rate_hz=50.0, frozen_after=None),
    SensorSpec(key="door", rate_hz=10.0, frozen_after=None),
    SensorSpec(key="front", rate_hz=20.0),
    SensorSpec(key="rear", rate_hz=20.0, silent_level=FailSafeLevel.SPEED_LIMIT),
)
MODULES = ("localization", "tracking", "decision", "planning", "control")


def _drive(
    seconds: float, out_dir: Path, radar_dies_at_s: float | None = None
) -> tuple[list[SafetyDirective], list[float], BlackBox]:
    scenario = dataclasses.replace(default_service(seed=0), minutes=seconds / 60.0)
    hdmap, sim, stack = build_closed_loop(scenario, "radar_tracking")
    sup = SafetySupervisor(
        HealthMonitor([ModuleSpec(name=m, period_us=100_000) for m in MODULES]),
        ReliabilityMonitor(ReliabilityConfig(sensors=SENSORS), hdmap=hdmap, route=stack.route),
        FailSafeArbiter(layers=stack.layers),
    )
    bb = BlackBox(BlackBoxConfig(out_dir=out_dir))
    watchdog = HardwareWatchdog()
    directives: list[SafetyDirective] = []
    speeds: list[float] = []
    for tick in range(round(seconds * 1e6 / TICK_US)):
        now = Stamp(tick * TICK_US)
        sim.advance_world(tick)
        frames = sim.sensor_frames(tick)
        if radar_dies_at_s is not None and now >= radar_dies_at_s * 1e6:
            frames = [f for f in frames if not (isinstance(f, RadarFrame) and f.sensor_id == "front")]
        sup.observe_frames(now, frames)
        out = stack.tick(now, frames)
        est = stack.ekf.estimate(now)
        directive = sup.step(
            now,
            out.heartbeats,
            estimate=est if tick % 10 == 0 else None,
            gate_rejections_total=stack.ekf.rejected_fixes,
            speed_mps=est.speed_mps,
        )
        assert out.command is not None
        command = apply_safety_gate(out.command, directive, est.speed_mps)
        command = watchdog.observe(now, command) or command
        bb.record_frames(now, frames)
        bb.record_output(now, out)
        bb.record(now, "/safety/directive", directive)
        if directive.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE and directive.since_us == now:
            bb.trigger(
                "emergency_stop" if directive.emergency_stop else "manual", now, "; ".join(directive.reasons)
            )
        sim.apply_command(command)
        sim.referee(out.takeover_request or directive.takeover_request)
        directives.append(directive)
        speeds.append(sim.world.ego.state.speed_mps)
    bb.close()
    return directives, speeds, bb


def test_healthy_run_raises_no_malfunction(tmp_path: Path) -> None:
    directives, speeds, bb = _drive(25.0, tmp_path)
    assert {d.level for d in directives} == {FailSafeLevel.NONE}
    assert max(speeds) > 2.0  # it did drive
    assert bb.dumps == []


def test_dead_front_radar_triggers_a_minimal_risk_manoeuvre_that_stops_the_shuttle(tmp_path: Path) -> None:
    dies_at = 12.0
    directives, speeds, bb = _drive(25.0, tmp_path, radar_dies_at_s=dies_at)
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
    (dump,) = bb.dumps
    rec = read_recording(dump)
    assert rec.events[0]["trigger"] == "manual" and "no frame" in rec.events[0]["reason"]
    assert rec.span_us == (0, first * TICK_US)  # everything up to the trigger (less than 30 s so far)
