"""A speed cap alone is ramped in at a comfortable jerk; manoeuvres and e-stops are not softened."""

from __future__ import annotations

from lastmile.core.safety_messages import FailSafeLevel, MrmKind, SafetyDirective
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand
from lastmile.safety.failsafe import FailSafeConfig, apply_safety_gate, ramp_speed_cap

C = FailSafeConfig()
TICK_US = 10_000


def _cmd(t_us: int, accel: float) -> ActuatorCommand:
    return ActuatorCommand(stamp=Stamp(t_us), accel_mps2=accel, steer_front_rad=0.0, steer_rear_rad=0.0)


def _gated_run(directive: SafetyDirective, stack_accel: float, ticks: int) -> list[float]:
    """The actuated accelerations, tick by tick at 100 Hz, from cruise at 3.5 m/s with the stack at
    ``stack_accel``."""
    previous = _cmd(0, 0.0)
    out = []
    for k in range(1, ticks + 1):
        stream = _cmd(k * TICK_US, stack_accel)
        gated = apply_safety_gate(stream, directive, 3.5, C)
        previous = ramp_speed_cap(gated, stream, previous, directive, C)
        out.append(previous.accel_mps2)
    return out


def test_a_speed_cap_brakes_at_the_comfortable_jerk_down_to_the_gate_floor() -> None:
    cap = SafetyDirective(stamp=Stamp(0), level=FailSafeLevel.SPEED_LIMIT, speed_cap_mps=0.5)
    accel = _gated_run(cap, 0.0, 100)
    steps = [b - a for a, b in zip([0.0, *accel], accel, strict=False)]
    assert min(steps) >= -C.cap_jerk_mps3 * TICK_US / 1e6 - 1e-12  # never faster than the jerk
    assert accel[-1] == -C.mrm_decel_mps2  # and the gate's floor is reached (in ~0.55 s)
    # The stack braking harder on its own passes unchanged.
    assert _gated_run(cap, -2.0, 3) == [-2.0, -2.0, -2.0]


def test_a_minimal_risk_manoeuvre_and_an_e_stop_are_not_ramped() -> None:
    mrm = SafetyDirective(
        stamp=Stamp(0),
        level=FailSafeLevel.MINIMAL_RISK_MANOEUVRE,
        mrm=MrmKind.STOP_IN_LANE,
        speed_cap_mps=0.5,
    )
    assert _gated_run(mrm, 0.0, 1)[0] == -C.mrm_decel_mps2
    stop = SafetyDirective(stamp=Stamp(0), level=FailSafeLevel.EMERGENCY_STOP, emergency_stop=True)
    assert _gated_run(stop, 0.0, 1)[0] == -C.max_decel_mps2
