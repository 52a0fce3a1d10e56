"""The hardware e-stop trigger: brakes fully when the stack's command stream stops (run by the simulator)."""

from __future__ import annotations

from dataclasses import dataclass

from lastmile.core.errors import ConfigError
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand, TurnSignal


@dataclass(frozen=True, slots=True, kw_only=True)
class HardwareWatchdogConfig:
    """Attributes:
    timeout_us: a command stream silent (no command with a newer stamp) for longer than this trips
        the watchdog; default 100 ms = 5 control periods at 50 Hz.
    brake_decel_mps2: deceleration commanded once tripped (the vehicle's maximum).
    latch: once tripped, stay tripped until :meth:`HardwareWatchdog.reset` (a real relay latches; a
        stack that comes back after hanging is not trusted without a human).
    """

    timeout_us: int = 100_000
    brake_decel_mps2: float = 5.0
    latch: bool = True

    def __post_init__(self) -> None:
        if self.timeout_us <= 0 or not self.brake_decel_mps2 > 0:
            raise ConfigError(
                "HardwareWatchdogConfig: expected timeout_us > 0 and brake_decel_mps2 > 0, got "
                f"{self.timeout_us}, {self.brake_decel_mps2}"
            )


class HardwareWatchdog:
    """A pure model of the watchdog relay between the computer and the drive-by-wire.

    It sees only the command stream. A command counts as fresh when its stamp is newer than the last
    fresh one: a stack that hangs (returns nothing) and a stack that keeps re-sending a stale command
    (its control loop frozen) both starve it. Nothing here reads a clock: ``now_us`` is the loop's.
    """

    def __init__(self, config: HardwareWatchdogConfig | None = None) -> None:
        self.config = config or HardwareWatchdogConfig()
        self._last_fresh_stamp_us: int | None = None
        self._last_fresh_at_us: int | None = None
        self._last_command: ActuatorCommand | None = None
        self.tripped_at_us: int | None = None

    @property
    def tripped(self) -> bool:
        return self.tripped_at_us is not None

    def reset(self) -> None:
        """The operator re-arms the relay; the stream must be fresh again or it trips at once."""
        self.tripped_at_us = None
        self._last_fresh_at_us = None

    def observe(self, now_us: int, command: ActuatorCommand | None) -> ActuatorCommand | None:
        """Feed the command the stack produced at ``now_us`` (None if it produced nothing).

        Returns:
            None while the stream is alive (pass the stack's command through), else the full-brake
            command the relay substitutes (steering held at the last command's angles).
        """
        if command is not None and (
            self._last_fresh_stamp_us is None or command.stamp > self._last_fresh_stamp_us
        ):
            self._last_fresh_stamp_us = int(command.stamp)
            self._last_fresh_at_us = int(now_us)
            self._last_command = command
        if self._last_fresh_at_us is None:
            self._last_fresh_at_us = int(now_us)  # armed from the first observation
        if (
            self.tripped
            and not self.config.latch
            and now_us - self._last_fresh_at_us <= self.config.timeout_us
        ):
            self.tripped_at_us = None
        if not self.tripped and now_us - self._last_fresh_at_us > self.config.timeout_us:
            self.tripped_at_us = int(now_us)
        if not self.tripped:
            return None
        last = self._last_command
        pedals = last is not None and last.has_pedals
        return ActuatorCommand(
            stamp=Stamp(int(now_us)),
            accel_mps2=-self.config.brake_decel_mps2,
            steer_front_rad=last.steer_front_rad if last is not None else 0.0,
            steer_rear_rad=last.steer_rear_rad if last is not None else 0.0,
            door_open=False,
            emergency_brake=True,
            turn_signal=TurnSignal.HAZARD,
            # A pedal vehicle's relay presses the brake pedal fully as well.
            throttle=0.0 if pedals else None,
            brake=1.0 if pedals else None,
        )
