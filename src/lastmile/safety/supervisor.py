"""Health monitor + reliability monitor -> fail-safe arbiter, stepped once a tick by the vehicle's safety."""

from __future__ import annotations

from collections.abc import Iterable

from lastmile.core.safety_messages import (
    FailSafeLevel,
    MalfunctionKind,
    MalfunctionSignal,
    SafetyDirective,
    SystemHealth,
)
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import Heartbeat, LocalizationEstimate
from lastmile.safety.failsafe import FailSafeArbiter
from lastmile.safety.health_monitor import HealthMonitor
from lastmile.safety.reliability_monitor import ReliabilityMonitor

RESET_GRACE_US = 1_000_000
"""How long past the e-stop's clear-hold an operator's release stays pending."""


class SafetySupervisor:
    """Composes the two monitors and the arbiter; holds the last health, signals and directive.

    Per tick, in order: :meth:`observe_frames` with the frames delivered this tick (before the stack
    uses them), then, after the stack's modules ran, :meth:`step` with their heartbeats and the pose.
    """

    def __init__(
        self, health: HealthMonitor, reliability: ReliabilityMonitor, arbiter: FailSafeArbiter
    ) -> None:
        self.health = health
        self.reliability = reliability
        self.arbiter = arbiter
        self.last_health: SystemHealth | None = None
        self.last_signals: tuple[MalfunctionSignal, ...] = ()
        self.last_directive: SafetyDirective | None = None
        self._operator_estop: MalfunctionSignal | None = None
        self._reset_until_us: int | None = None

    def operator_emergency_stop(self, now_us: int, reason: str) -> None:
        """The remote or on-board e-stop button: EMERGENCY_STOP until :meth:`operator_reset`.

        The signal stays active on every tick, not only the one it arrived on, so the arbiter's hold
        cannot time it out while the operator still holds the stop.
        """
        self._operator_estop = MalfunctionSignal(
            stamp=Stamp(int(now_us)),
            source="operator",
            kind=MalfunctionKind.OPERATOR_ESTOP,
            level=FailSafeLevel.EMERGENCY_STOP,
            reason=reason,
        )

    def operator_reset(self, now_us: int) -> None:
        """The operator releases the e-stop and confirms the cause is gone (effective at standstill).

        The arbiter holds EMERGENCY_STOP for its clear-hold after the last signal, and discards a reset
        that arrives while the level is still held. The release is therefore kept pending for that hold
        plus one second: the e-stop clears once the hold has run out, and a cause that is still there
        after the window keeps the shuttle stopped until the operator confirms again.
        """
        self._operator_estop = None
        hold_us = self.arbiter.config.clear_hold_us[FailSafeLevel.EMERGENCY_STOP]
        self._reset_until_us = int(now_us) + hold_us + RESET_GRACE_US

    def observe_frames(self, now_us: int, frames: Iterable[SensorFrame]) -> None:
        for frame in frames:
            self.reliability.observe_frame(now_us, frame)

    def step(
        self,
        now_us: int,
        heartbeats: Iterable[Heartbeat] = (),
        *,
        estimate: LocalizationEstimate | None = None,
        gate_rejections_total: int | None = None,
        gross_rejections_total: int | None = None,
        speed_mps: float = 0.0,
        route_s_m: float | None = None,
        extra_signals: tuple[MalfunctionSignal, ...] = (),
    ) -> SafetyDirective:
        """Pulse, check, arbitrate; returns the directive decision/control and the gate must obey.

        ``extra_signals`` come from outside the monitors (the loop's safety reporting a failed stack).
        """
        self.health.pulse_all(heartbeats)
        if estimate is not None:
            self.reliability.observe_localization(now_us, estimate)
        if gate_rejections_total is not None:
            self.reliability.observe_gate_rejections(now_us, gate_rejections_total, gross_rejections_total)
        health = self.health.check(now_us)
        signals = self.health.signals(health) + self.reliability.evaluate(now_us) + extra_signals
        if self._operator_estop is not None:
            signals = (*signals, self._operator_estop)
        if self._reset_until_us is not None:
            if now_us <= self._reset_until_us:
                self.arbiter.operator_reset()
            else:
                self._reset_until_us = None
        directive = self.arbiter.update(now_us, signals, speed_mps=speed_mps, route_s_m=route_s_m)
        if directive.level < FailSafeLevel.EMERGENCY_STOP:
            self._reset_until_us = None
        self.last_health, self.last_signals, self.last_directive = health, signals, directive
        return directive
