"""Process-health monitor: watchdogs catch silent modules, guarded calls contain raising ones."""

from __future__ import annotations

import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.safety_messages import FailSafeLevel, MalfunctionKind
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import Heartbeat
from lastmile.safety.health_monitor import HealthMonitor, HealthMonitorConfig, ModuleSpec
from lastmile.stack.module_guard import ModuleGuard

TICK_US = 10_000


def _monitor() -> HealthMonitor:
    return HealthMonitor(
        [
            ModuleSpec(name="planning", period_us=100_000),
            ModuleSpec(name="control", period_us=20_000, failure_level=FailSafeLevel.EMERGENCY_STOP),
        ]
    )


def _beat(now: int, module: str, healthy: bool = True, reason: str = "") -> Heartbeat:
    return Heartbeat(stamp=Stamp(now), module=module, healthy=healthy, reason=reason)


def test_frozen_module_is_caught_within_one_period_plus_timeout_margin() -> None:
    mon = _monitor()
    freeze_at = 1_000_000
    detected_at = None
    for tick in range(300):
        now = tick * TICK_US
        if now < freeze_at:
            if now % 100_000 == 0:
                mon.pulse(_beat(now, "planning"))
            if now % 20_000 == 0:
                mon.pulse(_beat(now, "control"))
        elif now % 20_000 == 0:
            mon.pulse(_beat(now, "control"))  # control keeps running; planning froze
        health = mon.check(now)
        planning = next(m for m in health.modules if m.module == "planning")
        if now < freeze_at:
            assert health.healthy, health
        elif not planning.healthy and detected_at is None:
            detected_at = now
            assert planning.silent
            assert all(m.healthy for m in health.modules if m.module != "planning")
    assert detected_at is not None
    last_beat = freeze_at - 100_000
    # Silent once the timeout (1 period + 50 ms) has passed, noticed at the next 10 ms check.
    assert detected_at == last_beat + mon.timeout_us("planning") + TICK_US
    assert detected_at - freeze_at <= 100_000 + 100_000  # within one period + 100 ms of the freeze


def test_silent_module_recovers_when_it_pulses_healthy_again() -> None:
    mon = _monitor()
    mon.pulse(_beat(0, "planning"))
    mon.pulse(_beat(0, "control"))
    assert not mon.check(400_000).healthy
    mon.pulse(_beat(400_000, "planning"))
    mon.pulse(_beat(400_000, "control"))
    assert mon.check(410_000).healthy


def test_raising_module_is_contained_and_reported_with_its_exception() -> None:
    mon = _monitor()
    mon.pulse(_beat(0, "control"))

    def broken_planner(x: int) -> int:
        raise ZeroDivisionError(f"division by zero at {x}")

    guard = ModuleGuard()
    assert guard.call("planning", Stamp(10_000), broken_planner, 7) is None
    mon.pulse_all(guard.drain())
    health = mon.check(10_000)
    planning = next(m for m in health.modules if m.module == "planning")
    assert not planning.healthy and not planning.silent
    assert planning.reason == "ZeroDivisionError: division by zero at 7"
    (signal,) = mon.signals(health)
    assert signal.kind == MalfunctionKind.MODULE_EXCEPTION
    assert signal.level == FailSafeLevel.MINIMAL_RISK_MANOEUVRE
    assert "ZeroDivisionError" in signal.reason
    # The next successful call is a healthy pulse again.
    assert guard.call("planning", Stamp(20_000), lambda: 42) == 42
    mon.pulse_all(guard.drain())
    assert mon.check(20_000).healthy


def test_unhealthy_pulse_holds_until_a_healthy_one_and_maps_to_the_module_level() -> None:
    mon = _monitor()
    mon.pulse(_beat(10_000, "planning"))
    mon.pulse(_beat(10_000, "control", healthy=False, reason="no path to follow"))
    health = mon.check(10_000)
    (signal,) = mon.signals(health)
    assert signal.kind == MalfunctionKind.MODULE_UNHEALTHY
    assert signal.level == FailSafeLevel.EMERGENCY_STOP
    assert "no path to follow" in signal.reason
    mon.pulse(_beat(5_000, "control"))  # a late pulse, older than the verdict, must not clear it
    assert not mon.check(15_000).healthy
    mon.pulse(_beat(20_000, "control"))
    assert mon.check(20_000).healthy


def test_module_never_heard_from_is_not_ready_then_silent_after_the_startup_grace() -> None:
    mon = HealthMonitor(
        [ModuleSpec(name="tracking", period_us=100_000)], HealthMonitorConfig(startup_grace_us=500_000)
    )
    first = mon.check(0)  # the first check starts the grace period
    assert not first.healthy and first.modules[0].reason == "no heartbeat yet"
    assert mon.signals(mon.check(400_000)) == ()  # not ready yet is not a malfunction
    h = mon.check(600_000)
    assert not h.healthy and h.modules[0].silent and h.modules[0].reason == "never sent a heartbeat"
    (signal,) = mon.signals(h)
    assert signal.kind == MalfunctionKind.MODULE_SILENT


def test_heartbeat_from_an_unknown_module_is_rejected_by_name() -> None:
    mon = _monitor()
    with pytest.raises(ConfigError, match="'planer'"):
        mon.pulse(_beat(0, "planer"))
    with pytest.raises(ConfigError, match="timeout_factor"):
        HealthMonitorConfig(timeout_factor=0.5)
