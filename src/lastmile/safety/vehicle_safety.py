"""The vehicle's safety, apart from the software it watches: supervisor, actuator gate, hardware watchdog.

The loop owns one of these per vehicle. It sees the frames the vehicle receives (before the software
does), the software's output and diagnostics after it ran, and decides what reaches the drive-by-wire.
It keeps working when the software raises or stops producing commands: a raise is an emergency stop,
a silent or frozen command stream trips the watchdog relay. Operator inputs (e-stop, reset) arrive as
:class:`~lastmile.core.safety_messages.OperatorInput` frames.
"""

from __future__ import annotations

from collections.abc import Sequence

from lastmile.core.errors import MessageError
from lastmile.core.pedal_map import gem_brake_pedal
from lastmile.core.safety_messages import (
    FailSafeLevel,
    MalfunctionKind,
    MalfunctionSignal,
    OperatorAction,
    OperatorInput,
    SafetyDirective,
)
from lastmile.core.sensor_frames import SensorFrame, WheelOdometryFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand, SafetyVerdict, StackOutput, TurnSignal
from lastmile.safety.failsafe import apply_safety_gate
from lastmile.safety.hardware_watchdog import HardwareWatchdog
from lastmile.safety.supervisor import SafetySupervisor


class VehicleSafety:
    """Supervisor (health, reliability, arbitration), actuator gate and hardware watchdog in one object.

    Per tick, in loop order: :meth:`observe` with the frames delivered this tick, then (after the
    software ran) :meth:`step` with its output, or None when it raised. :attr:`directive` is what the
    software is handed on its next tick.
    """

    def __init__(self, supervisor: SafetySupervisor, watchdog: HardwareWatchdog | None = None) -> None:
        self.supervisor = supervisor
        self.watchdog = watchdog or HardwareWatchdog()
        self.directive: SafetyDirective | None = None
        # The safety reads the wheel speed itself: the gate must not depend on the software it gates.
        self._wheel_speed_mps = 0.0
        self._last_command: ActuatorCommand | None = None

    def observe(self, now: Stamp, frames: Sequence[SensorFrame]) -> None:
        """The frames delivered at ``now``, before the software sees them."""
        self.supervisor.observe_frames(int(now), frames)
        for frame in frames:
            if isinstance(frame, OperatorInput):
                self._operator(frame)
            elif isinstance(frame, WheelOdometryFrame):
                try:
                    frame.validate()
                except MessageError:
                    continue  # the reliability monitor flags the stream; the last good speed stands
                self._wheel_speed_mps = frame.speed_mps

    def _operator(self, frame: OperatorInput) -> None:
        if frame.action is OperatorAction.EMERGENCY_STOP:
            self.supervisor.operator_emergency_stop(int(frame.stamp), frame.reason or "operator e-stop")
        else:
            self.supervisor.operator_reset(int(frame.stamp))
            if self.watchdog.tripped:
                self.watchdog.reset()  # the operator re-arms the relay; a dead stream trips it again

    def step(self, now: Stamp, output: StackOutput | None, failure: str = "") -> SafetyVerdict:
        """Arbitrate, gate the software's command and watch its command stream.

        Args:
            output: what the software returned this tick, None if it raised.
            failure: the exception text when it raised (the malfunction's reason).
        """
        diag = output.diagnostics if output is not None else None
        extra: tuple[MalfunctionSignal, ...] = ()
        if output is None:
            extra = (
                MalfunctionSignal(
                    stamp=now,
                    source="stack",
                    kind=MalfunctionKind.STACK_FAILED,
                    level=FailSafeLevel.EMERGENCY_STOP,
                    reason=f"vehicle software failed: {failure or 'no output'}",
                ),
            )
        directive = self.supervisor.step(
            int(now),
            output.heartbeats if output is not None else (),
            estimate=diag.estimate if diag is not None else None,
            gate_rejections_total=diag.gate_rejections_total if diag is not None else None,
            gross_rejections_total=diag.gross_rejections_total if diag is not None else None,
            speed_mps=diag.speed_mps if diag is not None else self._wheel_speed_mps,
            route_s_m=diag.front_route_s_m if diag is not None else None,
            extra_signals=extra,
        )
        self.directive = directive
        stream = output.command if output is not None else None
        front_s = diag.front_route_s_m if diag is not None else None
        command = (
            apply_safety_gate(
                stream,
                directive,
                self._wheel_speed_mps,
                self.supervisor.arbiter.config,
                mrm_gap_m=self.supervisor.arbiter.mrm_gap_m(front_s),
            )
            if stream is not None
            else self._own_brake(now, directive)
        )
        if stream is not None:
            self._last_command = stream
        brake = self.watchdog.observe(int(now), stream)
        return SafetyVerdict(
            stamp=now,
            directive=directive,
            command=brake if brake is not None else command,
            watchdog_tripped=self.watchdog.tripped,
            stack_failed=output is None,
        )

    def _own_brake(self, now: Stamp, directive: SafetyDirective) -> ActuatorCommand:
        """No command from the software: brake as the directive asks, steering held where it was."""
        c = self.supervisor.arbiter.config
        last = self._last_command
        emergency = directive.level >= FailSafeLevel.EMERGENCY_STOP
        decel = c.max_decel_mps2 if emergency else c.mrm_decel_mps2
        # A pedal vehicle (the last command carried pedals) brakes by its pedal too.
        pedal_vehicle = last is not None and last.has_pedals
        return ActuatorCommand(
            stamp=now,
            accel_mps2=-decel,
            steer_front_rad=last.steer_front_rad if last is not None else 0.0,
            steer_rear_rad=last.steer_rear_rad if last is not None else 0.0,
            emergency_brake=emergency,
            turn_signal=TurnSignal.HAZARD,  # the vehicle's own brake: the software has failed
            throttle=0.0 if pedal_vehicle else None,
            brake=(1.0 if emergency else gem_brake_pedal(decel)) if pedal_vehicle else None,
        )
