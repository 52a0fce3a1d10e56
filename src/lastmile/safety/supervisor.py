"""One object for the stack to call each tick: health monitor + reliability monitor -> fail-safe arbiter."""

from __future__ import annotations

from collections.abc import Iterable

from lastmile.core.safety_messages import MalfunctionSignal, SafetyDirective, SystemHealth
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.vehicle_messages import Heartbeat, LocalizationEstimate
from lastmile.safety.failsafe import FailSafeArbiter
from lastmile.safety.health_monitor import HealthMonitor
from lastmile.safety.reliability_monitor import ReliabilityMonitor


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
        speed_mps: float = 0.0,
        route_s_m: float | None = None,
    ) -> SafetyDirective:
        """Pulse, check, arbitrate; returns the directive decision/control and the gate must obey."""
        self.health.pulse_all(heartbeats)
        if estimate is not None:
            self.reliability.observe_localization(now_us, estimate)
        if gate_rejections_total is not None:
            self.reliability.observe_gate_rejections(now_us, gate_rejections_total)
        health = self.health.check(now_us)
        signals = self.health.signals(health) + self.reliability.evaluate(now_us)
        directive = self.arbiter.update(now_us, signals, speed_mps=speed_mps, route_s_m=route_s_m)
        self.last_health, self.last_signals, self.last_directive = health, signals, directive
        return directive
