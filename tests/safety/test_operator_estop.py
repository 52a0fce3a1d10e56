from lastmile.core.safety_messages import FailSafeLevel as L
from lastmile.core.safety_messages import MalfunctionKind as K
from lastmile.safety.failsafe import FailSafeArbiter
from lastmile.safety.health_monitor import HealthMonitor
from lastmile.safety.reliability_config import ReliabilityConfig
from lastmile.safety.reliability_monitor import ReliabilityMonitor
from lastmile.safety.supervisor import RESET_GRACE_US, SafetySupervisor

TICK_US = 10_000


def _supervisor() -> SafetySupervisor:
    # No modules, no sensors and no pose to watch: only the operator's button can raise a level.
    quiet = {K.LOCALIZATION_INVALID: L.NONE, K.GNSS_LOST: L.NONE}
    reliability = ReliabilityMonitor(ReliabilityConfig(sensors=(), levels=quiet))
    return SafetySupervisor(HealthMonitor([]), reliability, FailSafeArbiter())


def test_the_button_holds_emergency_stop_while_pressed_and_clears_after_release_at_standstill() -> None:
    sup = _supervisor()
    assert sup.step(0).level == L.NONE
    sup.operator_emergency_stop(TICK_US, "button")
    levels = [sup.step(t, speed_mps=3.0).level for t in range(TICK_US, 30 * 1_000_000, TICK_US)]
    assert set(levels) == {L.EMERGENCY_STOP}  # pressed for 30 s: never timed out by the arbiter's hold
    release_us = 30 * 1_000_000
    sup.operator_reset(release_us)
    hold_us = sup.arbiter.config.clear_hold_us[L.EMERGENCY_STOP]
    t = release_us
    while sup.step(t, speed_mps=0.0).level == L.EMERGENCY_STOP:
        t += TICK_US
        assert t < release_us + hold_us + RESET_GRACE_US, "the release never took effect"
    assert t - release_us >= hold_us - TICK_US  # the e-stop's hold still ran its course


def test_a_release_while_rolling_waits_for_standstill() -> None:
    sup = _supervisor()
    sup.operator_emergency_stop(0, "button")
    sup.step(0, speed_mps=3.0)
    sup.operator_reset(10_000)
    hold_us = sup.arbiter.config.clear_hold_us[L.EMERGENCY_STOP]
    assert sup.step(hold_us + 100_000, speed_mps=1.0).level == L.EMERGENCY_STOP
    assert sup.step(hold_us + 200_000, speed_mps=0.0).level == L.NONE


def test_a_release_that_lapses_leaves_the_stop_latched() -> None:
    sup = _supervisor()
    sup.operator_emergency_stop(0, "button")
    sup.step(0, speed_mps=0.0)
    sup.operator_reset(10_000)
    hold_us = sup.arbiter.config.clear_hold_us[L.EMERGENCY_STOP]
    # The shuttle keeps rolling past the release window (say, pushed): the release lapses.
    late = 10_000 + hold_us + RESET_GRACE_US + 100_000
    assert sup.step(late, speed_mps=0.5).level == L.EMERGENCY_STOP
    assert sup.step(late + 100_000, speed_mps=0.0).level == L.EMERGENCY_STOP
