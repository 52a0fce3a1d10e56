"""The vehicle's safety on a throttle/brake vehicle: every intervention reaches the pedals."""

from __future__ import annotations

import pytest

from lastmile.core.pedal_map import brake_decel_mps2, gem_brake_pedal
from lastmile.core.safety_messages import FailSafeLevel, MalfunctionKind, MalfunctionSignal, SafetyDirective
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand
from lastmile.safety.failsafe import FailSafeArbiter, apply_safety_gate
from lastmile.safety.hardware_watchdog import HardwareWatchdog, HardwareWatchdogConfig

L, K = FailSafeLevel, MalfunctionKind


def _directive(level: FailSafeLevel, kind: MalfunctionKind, cap: float | None = None) -> SafetyDirective:
    signal = MalfunctionSignal(
        stamp=Stamp(0), source="x", kind=kind, level=level, reason="x", speed_cap_mps=cap
    )
    return FailSafeArbiter().update(0, [signal], speed_mps=3.0)


def _pedal_cmd(accel: float = 0.6, throttle: float = 0.5, brake: float = 0.0) -> ActuatorCommand:
    return ActuatorCommand(
        stamp=Stamp(0),
        accel_mps2=accel,
        steer_front_rad=0.1,
        steer_rear_rad=0.0,
        throttle=throttle,
        brake=brake,
    )


def test_emergency_stop_presses_the_brake_pedal_fully_and_releases_the_throttle() -> None:
    out = apply_safety_gate(_pedal_cmd(), _directive(L.EMERGENCY_STOP, K.OFF_MAP), 3.0)
    assert out.emergency_brake and out.throttle == 0.0 and out.brake == 1.0


def test_speed_cap_and_mrm_release_the_throttle_and_brake_by_gems_map() -> None:
    capped = apply_safety_gate(_pedal_cmd(), _directive(L.SPEED_LIMIT, K.SENSOR_NOISE, cap=0.5), 3.0)
    assert capped.accel_mps2 == pytest.approx(-1.0)
    assert capped.throttle == 0.0 and brake_decel_mps2(capped.brake or 0.0) == pytest.approx(1.0)
    mrm = apply_safety_gate(_pedal_cmd(), _directive(L.MINIMAL_RISK_MANOEUVRE, K.SENSOR_SILENT), 3.0)
    assert mrm.throttle == 0.0 and mrm.brake == pytest.approx(gem_brake_pedal(-mrm.accel_mps2))
    # The stack's harder brake is kept.
    hard = _pedal_cmd(accel=-1.4, throttle=0.0, brake=0.99)
    assert apply_safety_gate(hard, _directive(L.MINIMAL_RISK_MANOEUVRE, K.SENSOR_SILENT), 3.0).brake == 0.99


def test_a_cap_above_the_speed_keeps_the_stacks_pedals() -> None:
    cmd = _pedal_cmd()
    out = apply_safety_gate(cmd, _directive(L.SPEED_LIMIT, K.SENSOR_NOISE, cap=8.0), 3.0)
    assert (out.throttle, out.brake) == (cmd.throttle, cmd.brake)


def test_an_acceleration_command_stays_without_pedals() -> None:
    cmd = ActuatorCommand(stamp=Stamp(0), accel_mps2=0.6, steer_front_rad=0.0, steer_rear_rad=0.0)
    out = apply_safety_gate(cmd, _directive(L.EMERGENCY_STOP, K.OFF_MAP), 3.0)
    assert out.throttle is None and out.brake is None and out.emergency_brake


def test_the_watchdog_relay_brakes_a_pedal_vehicle_by_its_pedal() -> None:
    wd = HardwareWatchdog(HardwareWatchdogConfig(timeout_us=100_000))
    wd.observe(0, _pedal_cmd())
    tripped = wd.observe(200_000, None)
    assert tripped is not None and tripped.emergency_brake and (tripped.throttle, tripped.brake) == (0.0, 1.0)
