"""Fail-safe arbitration by priority with latching, the actuator gate, and the hardware watchdog."""

from __future__ import annotations

import dataclasses

import pytest

from lastmile.core.safety_messages import FailSafeLevel, MalfunctionKind, MalfunctionSignal, MrmKind
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand, TurnSignal
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.safety.failsafe import FailSafeArbiter, FailSafeConfig, apply_safety_gate
from lastmile.safety.hardware_watchdog import HardwareWatchdog, HardwareWatchdogConfig

K, L = MalfunctionKind, FailSafeLevel


def _sig(
    level: FailSafeLevel, kind: MalfunctionKind = K.SENSOR_NOISE, cap: float | None = None, src: str = "x"
) -> MalfunctionSignal:
    return MalfunctionSignal(
        stamp=Stamp(0), source=src, kind=kind, level=level, reason=f"{src} {kind.value}", speed_cap_mps=cap
    )


def _cmd(t: int, accel: float = 0.8) -> ActuatorCommand:
    return ActuatorCommand(
        stamp=Stamp(t), accel_mps2=accel, steer_front_rad=0.1, steer_rear_rad=-0.1, door_open=False
    )


def test_highest_priority_signal_wins_and_caps_combine_by_minimum() -> None:
    arb = FailSafeArbiter()
    d = arb.update(
        0, [_sig(L.SPEED_LIMIT, cap=2.0, src="a"), _sig(L.SPEED_LIMIT, cap=1.0, src="b")], speed_mps=3.0
    )
    assert d.level == L.SPEED_LIMIT and d.speed_cap_mps == 1.0 and not d.takeover_request
    d = arb.update(
        10_000, [_sig(L.SPEED_LIMIT, cap=1.0), _sig(L.TAKEOVER_REQUEST, K.GNSS_LOST)], speed_mps=3.0
    )
    assert d.level == L.TAKEOVER_REQUEST and d.takeover_request and d.mrm == MrmKind.NONE
    d = arb.update(
        20_000, [_sig(L.TAKEOVER_REQUEST), _sig(L.MINIMAL_RISK_MANOEUVRE, K.SENSOR_SILENT)], speed_mps=3.0
    )
    assert d.level == L.MINIMAL_RISK_MANOEUVRE and d.mrm == MrmKind.STOP_IN_LANE
    d = arb.update(30_000, [_sig(L.EMERGENCY_STOP, K.OFF_MAP)], speed_mps=3.0)
    assert d.level == L.EMERGENCY_STOP and d.emergency_stop and d.speed_cap_mps == 0.0
    d.validate()


def test_levels_latch_for_their_hold_then_step_down() -> None:
    cfg = FailSafeConfig()
    arb = FailSafeArbiter(cfg)
    arb.update(
        0, [_sig(L.MINIMAL_RISK_MANOEUVRE, K.SENSOR_SILENT), _sig(L.SPEED_LIMIT, cap=1.0)], speed_mps=2.0
    )
    hold = cfg.clear_hold_us[L.MINIMAL_RISK_MANOEUVRE]
    # The cause clears at once but the manoeuvre holds for its clear time (hysteresis).
    assert arb.update(hold - 10_000, [], speed_mps=0.0).level == L.MINIMAL_RISK_MANOEUVRE
    d = arb.update(hold, [], speed_mps=0.0)
    assert d.level == L.NONE  # the speed limit's own (shorter) hold ran out long ago
    assert [h[2] for h in arb.history] == ["MINIMAL_RISK_MANOEUVRE", "NONE"]


def test_emergency_stop_needs_standstill_and_operator_reset() -> None:
    cfg = FailSafeConfig()
    arb = FailSafeArbiter(cfg)
    arb.update(0, [_sig(L.EMERGENCY_STOP, K.LOCALIZATION_INVALID)], speed_mps=4.0)
    late = cfg.clear_hold_us[L.EMERGENCY_STOP] * 3
    assert arb.update(late, [], speed_mps=0.0).level == L.EMERGENCY_STOP  # no reset yet
    arb.operator_reset()
    assert arb.update(late + 10_000, [], speed_mps=1.0).level == L.EMERGENCY_STOP  # still rolling
    assert arb.update(late + 20_000, [], speed_mps=0.0).level == L.NONE


def test_reset_does_not_clear_an_emergency_whose_cause_is_still_there() -> None:
    arb = FailSafeArbiter()
    arb.update(0, [_sig(L.EMERGENCY_STOP, K.OFF_MAP)], speed_mps=0.0)
    arb.operator_reset()
    assert arb.update(10_000, [_sig(L.EMERGENCY_STOP, K.OFF_MAP)], speed_mps=0.0).level == L.EMERGENCY_STOP
    assert arb.update(20_000, [], speed_mps=0.0).level == L.EMERGENCY_STOP


def test_mrm_pulls_over_where_a_curb_is_near_unless_the_pose_is_in_doubt(
    straight_layers: SLayerDatabase,
) -> None:
    arb = FailSafeArbiter(layers=straight_layers)
    d = arb.update(0, [_sig(L.MINIMAL_RISK_MANOEUVRE, K.WEATHER_VISIBILITY)], speed_mps=4.0, route_s_m=150.0)
    assert d.mrm == MrmKind.PULL_OVER
    # Past the comfortable stopping point (8 m) and far enough for the planner's move to the curb.
    assert d.mrm_stop_s_m == pytest.approx(150.0 + FailSafeConfig().pullover_min_ahead_m, abs=1.0)
    arb2 = FailSafeArbiter(layers=straight_layers)
    d2 = arb2.update(
        0, [_sig(L.MINIMAL_RISK_MANOEUVRE, K.LOCALIZATION_COVARIANCE)], speed_mps=4.0, route_s_m=150.0
    )
    assert d2.mrm == MrmKind.STOP_IN_LANE and d2.mrm_stop_s_m == pytest.approx(158.0)


def test_gate_enforces_each_level_on_the_command() -> None:
    arb = FailSafeArbiter()
    cmd = _cmd(0, accel=0.8)
    none = arb.update(0, [], speed_mps=3.0)
    assert apply_safety_gate(cmd, none, 3.0) is cmd
    capped = FailSafeArbiter().update(0, [_sig(L.SPEED_LIMIT, cap=0.5)], speed_mps=3.0)
    out = apply_safety_gate(cmd, capped, 3.0)
    assert out.accel_mps2 == pytest.approx(-1.0) and out.steer_front_rad == cmd.steer_front_rad
    assert apply_safety_gate(cmd, capped, 0.2).accel_mps2 == pytest.approx(0.3)
    mrm = FailSafeArbiter().update(0, [_sig(L.MINIMAL_RISK_MANOEUVRE, K.SENSOR_SILENT)], speed_mps=3.0)
    assert apply_safety_gate(cmd, mrm, 3.0).accel_mps2 == pytest.approx(-1.0)
    assert apply_safety_gate(_cmd(0, accel=-3.0), mrm, 3.0).accel_mps2 == -3.0  # a harder brake is kept
    estop = FailSafeArbiter().update(0, [_sig(L.EMERGENCY_STOP, K.OFF_MAP)], speed_mps=3.0)
    out = apply_safety_gate(cmd, estop, 3.0)
    assert out.emergency_brake and out.accel_mps2 == -5.0 and out.steer_front_rad == 0.1


def test_gate_puts_the_hazard_lights_on_from_a_minimal_risk_manoeuvre_up() -> None:
    cmd = dataclasses.replace(_cmd(0, accel=-3.0), turn_signal=TurnSignal.LEFT)
    capped = FailSafeArbiter().update(0, [_sig(L.SPEED_LIMIT, cap=5.0)], speed_mps=3.0)
    assert apply_safety_gate(cmd, capped, 3.0).turn_signal is TurnSignal.LEFT
    for level, kind in ((L.MINIMAL_RISK_MANOEUVRE, K.SENSOR_SILENT), (L.EMERGENCY_STOP, K.OFF_MAP)):
        directive = FailSafeArbiter().update(0, [_sig(level, kind)], speed_mps=3.0)
        # The stack's harder brake is kept under an MRM: only the lights change.
        assert apply_safety_gate(cmd, directive, 3.0).turn_signal is TurnSignal.HAZARD, level
    wd = HardwareWatchdog(HardwareWatchdogConfig(timeout_us=100_000))
    wd.observe(0, cmd)
    tripped = wd.observe(200_000, None)
    assert tripped is not None and tripped.turn_signal is TurnSignal.HAZARD


def test_hardware_watchdog_brakes_when_the_command_stream_stops() -> None:
    wd = HardwareWatchdog(HardwareWatchdogConfig(timeout_us=100_000))
    for tick in range(100):
        assert wd.observe(tick * 10_000, _cmd(tick * 10_000)) is None
    hang_at = 100 * 10_000
    tripped_at = None
    for tick in range(100, 200):
        now = tick * 10_000
        out = wd.observe(now, None)
        if out is not None:
            tripped_at = now
            assert out.emergency_brake and out.accel_mps2 == -5.0 and out.steer_front_rad == 0.1
            break
    assert tripped_at is not None
    assert tripped_at - (hang_at - 10_000) == 110_000  # first tick past the 100 ms timeout
    # Latched: the stack coming back does not release the brake without a reset.
    assert wd.observe(tripped_at + 10_000, _cmd(tripped_at + 10_000)) is not None
    wd.reset()
    assert wd.observe(tripped_at + 20_000, _cmd(tripped_at + 20_000)) is None


def test_hardware_watchdog_trips_on_a_stale_command_repeated_by_a_frozen_loop() -> None:
    wd = HardwareWatchdog()
    stale = _cmd(0)
    outs = [wd.observe(t * 10_000, stale) for t in range(20)]
    assert outs[10] is None and outs[11] is not None


def test_mrm_gate_enforces_the_stop_point_rather_than_a_fixed_deceleration() -> None:
    mrm = FailSafeArbiter().update(0, [_sig(L.MINIMAL_RISK_MANOEUVRE, K.SENSOR_SILENT)], speed_mps=3.0)
    cruise = _cmd(0, accel=0.0)
    # Far from the point: the stack's own gentler braking (or coasting) stands, no fixed 1 m/s^2.
    assert apply_safety_gate(_cmd(0, accel=-0.4), mrm, 3.0, mrm_gap_m=30.0).accel_mps2 == -0.4
    # Nothing of the motion is changed; only the hazard lights go on.
    hazard = dataclasses.replace(cruise, turn_signal=TurnSignal.HAZARD)
    assert apply_safety_gate(cruise, mrm, 3.0, mrm_gap_m=30.0) == hazard
    # Too fast for the point: at least the braking that still stops there (v^2 / 2 gap).
    assert apply_safety_gate(cruise, mrm, 5.0, mrm_gap_m=5.0).accel_mps2 == pytest.approx(-2.5)
    # Stopped short of the point: it may creep on toward it; at the point the brake is held.
    assert apply_safety_gate(_cmd(0, accel=0.3), mrm, 0.0, mrm_gap_m=10.0).accel_mps2 == 0.3
    assert apply_safety_gate(_cmd(0, accel=0.3), mrm, 0.0, mrm_gap_m=0.0).accel_mps2 == pytest.approx(-1.0)
    # Without the front's position the old rule stands: at least the MRM's deceleration.
    assert apply_safety_gate(cruise, mrm, 3.0).accel_mps2 == pytest.approx(-1.0)
