"""The fail-safe arbiter's steps, each on its own: hold, latch, caps, reasons, level changes."""

from __future__ import annotations

from lastmile.core.safety_messages import FailSafeLevel, MalfunctionKind, MalfunctionSignal, MrmKind
from lastmile.core.stamp import Stamp
from lastmile.safety.failsafe import (
    EStopLatch,
    FailSafeArbiter,
    FailSafeConfig,
    combined_speed_cap_mps,
    held_level,
    reasons_at_or_below,
    signal_speed_cap_mps,
    worst_first_reasons,
)

K, L = MalfunctionKind, FailSafeLevel
HOLD = FailSafeConfig().clear_hold_us


def _sig(
    level: FailSafeLevel, kind: MalfunctionKind = K.SENSOR_NOISE, cap: float | None = None
) -> MalfunctionSignal:
    return MalfunctionSignal(
        stamp=Stamp(0),
        source="m",
        kind=kind,
        level=level,
        reason=f"{level.name} {kind.value}",
        speed_cap_mps=cap,
    )


def test_held_level_is_the_highest_level_still_inside_its_hold() -> None:
    seen = {L.SPEED_LIMIT: 0, L.TAKEOVER_REQUEST: 0}
    assert held_level(seen, HOLD[L.SPEED_LIMIT] - 1, HOLD) == L.TAKEOVER_REQUEST
    # The speed limit's hold (2 s) runs out before the takeover request's (3 s) ...
    assert held_level(seen, HOLD[L.TAKEOVER_REQUEST] - 1, HOLD) == L.TAKEOVER_REQUEST
    # ... and at exactly the hold the level is no longer held.
    assert held_level(seen, HOLD[L.TAKEOVER_REQUEST], HOLD) == L.NONE
    assert held_level({}, 0, HOLD) == L.NONE


def test_held_level_prefers_a_younger_lower_level_over_an_expired_higher_one() -> None:
    seen = {L.EMERGENCY_STOP: 0, L.SPEED_LIMIT: 4_900_000}
    assert held_level(seen, 4_999_999, HOLD) == L.EMERGENCY_STOP
    assert held_level(seen, 5_000_000, HOLD) == L.SPEED_LIMIT


def test_estop_latch_holds_until_standstill_and_reset() -> None:
    latch = EStopLatch()
    assert latch.apply(L.EMERGENCY_STOP, stopped=False, needs_reset=True) == L.EMERGENCY_STOP
    # The cause is gone but the vehicle still rolls: held.
    assert latch.apply(L.NONE, stopped=False, needs_reset=True) == L.EMERGENCY_STOP
    # Stopped, but nobody confirmed: held.
    assert latch.apply(L.SPEED_LIMIT, stopped=True, needs_reset=True) == L.EMERGENCY_STOP
    latch.request_reset()
    assert latch.apply(L.SPEED_LIMIT, stopped=True, needs_reset=True) == L.SPEED_LIMIT
    assert not latch.latched and not latch.reset_requested


def test_estop_latch_discards_a_reset_given_while_the_estop_is_still_signalled() -> None:
    latch = EStopLatch()
    latch.request_reset()
    assert latch.apply(L.EMERGENCY_STOP, stopped=True, needs_reset=True) == L.EMERGENCY_STOP
    assert latch.apply(L.NONE, stopped=True, needs_reset=True) == L.EMERGENCY_STOP


def test_estop_latch_without_reset_releases_at_standstill() -> None:
    latch = EStopLatch()
    latch.apply(L.EMERGENCY_STOP, stopped=False, needs_reset=False)
    assert latch.apply(L.NONE, stopped=False, needs_reset=False) == L.EMERGENCY_STOP
    assert latch.apply(L.NONE, stopped=True, needs_reset=False) == L.NONE


def test_signal_speed_cap_defaults_only_for_speed_limit_signals() -> None:
    assert signal_speed_cap_mps(_sig(L.SPEED_LIMIT), 0.5) == 0.5
    assert signal_speed_cap_mps(_sig(L.SPEED_LIMIT, cap=1.5), 0.5) == 1.5
    assert signal_speed_cap_mps(_sig(L.TAKEOVER_REQUEST), 0.5) is None
    assert signal_speed_cap_mps(_sig(L.TAKEOVER_REQUEST, cap=2.0), 0.5) == 2.0


def test_combined_speed_cap_is_the_minimum_zero_at_estop_and_none_at_none() -> None:
    caps = {"a/x": (2.0, 0), "b/y": (1.0, 0)}
    assert combined_speed_cap_mps(caps, L.SPEED_LIMIT) == 1.0
    assert combined_speed_cap_mps(caps, L.MINIMAL_RISK_MANOEUVRE) == 1.0
    assert combined_speed_cap_mps(caps, L.NONE) is None
    assert combined_speed_cap_mps(caps, L.EMERGENCY_STOP) == 0.0
    assert combined_speed_cap_mps({}, L.TAKEOVER_REQUEST) is None


def test_reasons_are_those_of_the_top_level_most_severe_first() -> None:
    active = [_sig(L.SPEED_LIMIT), _sig(L.NONE), _sig(L.MINIMAL_RISK_MANOEUVRE, K.SENSOR_SILENT)]
    top, reasons = worst_first_reasons(active)
    assert top == L.MINIMAL_RISK_MANOEUVRE
    assert reasons == ("MINIMAL_RISK_MANOEUVRE sensor_silent", "SPEED_LIMIT sensor_noise")
    assert worst_first_reasons([_sig(L.NONE)]) == (L.NONE, ())
    assert worst_first_reasons([]) == (L.NONE, ())


def test_reasons_held_are_those_of_the_highest_recorded_level_not_above_the_held_one() -> None:
    recorded = {L.SPEED_LIMIT: ("slow",), L.EMERGENCY_STOP: ("stop",)}
    assert reasons_at_or_below(recorded, L.EMERGENCY_STOP) == ("stop",)
    assert reasons_at_or_below(recorded, L.MINIMAL_RISK_MANOEUVRE) == ("slow",)
    assert reasons_at_or_below(recorded, L.NONE) == ()


def test_record_notes_every_level_up_to_the_signal_and_pullover_blockers() -> None:
    arb = FailSafeArbiter()
    assert not arb._record(7, [_sig(L.TAKEOVER_REQUEST, K.SENSOR_NOISE)])
    assert arb._last_seen == {L.SPEED_LIMIT: 7, L.TAKEOVER_REQUEST: 7}
    assert arb._record(9, [_sig(L.SPEED_LIMIT, K.GNSS_LOST, cap=1.0)])
    assert arb._caps == {"m/gnss_lost": (1.0, 9)}
    # A NONE signal is ignored, even of a blocking kind.
    assert not arb._record(11, [_sig(L.NONE, K.GNSS_LOST)])
    assert arb._last_seen[L.SPEED_LIMIT] == 9


def test_a_new_manoeuvre_is_planned_on_escalation_and_dropped_below_it() -> None:
    arb = FailSafeArbiter()
    d = arb.update(0, [_sig(L.MINIMAL_RISK_MANOEUVRE)], speed_mps=2.0, route_s_m=10.0)
    assert d.mrm == MrmKind.STOP_IN_LANE and d.mrm_stop_s_m == 10.0 + 2.0**2 / 2.0
    # Further on, still held: the stopping point does not run away.
    d = arb.update(10_000, [_sig(L.MINIMAL_RISK_MANOEUVRE)], speed_mps=2.0, route_s_m=12.0)
    assert d.mrm_stop_s_m == 12.0
    # Escalating to an e-stop keeps the manoeuvre's point (it is already at or above the MRM).
    d = arb.update(20_000, [_sig(L.EMERGENCY_STOP)], speed_mps=2.0, route_s_m=13.0)
    assert d.emergency_stop and d.mrm_stop_s_m == 12.0
    arb._enter_level(30_000, L.SPEED_LIMIT)
    assert arb._mrm == MrmKind.NONE and arb._mrm_stop_s is None
    assert arb.history[-1] == (30_000, "EMERGENCY_STOP", "SPEED_LIMIT")
