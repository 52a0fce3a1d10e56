"""Signal controller: what every mapped traffic signal shows at time t (fixed-time cycle or flashing).

A fixed-time controller runs green -> yellow -> red -> green; the flashing modes are what a signal
falls back to at night or on a fault: flashing red (drivers treat it as a stop sign) or flashing
yellow (proceed with caution). Flashing follows the MUTCD: 50 to 60 flashes a minute, lit between
half and two thirds of each cycle. All signals of the map share one controller phase (the campus has
one signalised crossing, whose two directions always show the same state).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.config import check_range
from lastmile.core.errors import ConfigError
from lastmile.core.traffic_light_messages import LightState

SIGNAL_MODES = ("cycle", "flashing_red", "flashing_yellow", "dark")


@dataclass(frozen=True, slots=True, kw_only=True)
class SignalConfig:
    """The controller's timing (a scenario's ``[traffic_signals]`` table).

    Attributes:
        mode: "cycle" (fixed time), "flashing_red", "flashing_yellow" or "dark" (power cut).
        green_s, yellow_s, red_s: phase durations of the cycle (s); yellow 3-6 s as ITE recommends.
            With the defaults (30 / 3.5 / 20 s) the default service meets the crossing on red in
            seeds 1 and 2 and on green in seeds 0, 3 and 4.
        offset_s: where in the cycle the controller is at t = 0 (s from the start of green).
        flash_period_s: one flash cycle (s): 1.0-1.2 s is 60-50 flashes a minute.
        flash_on_fraction: share of a flash cycle the bulb is lit (MUTCD: 1/2 to 2/3).
    """

    mode: str = "cycle"
    green_s: float = 30.0
    yellow_s: float = 3.5
    red_s: float = 20.0
    offset_s: float = 0.0
    flash_period_s: float = 1.0
    flash_on_fraction: float = 0.6

    def __post_init__(self) -> None:
        if self.mode not in SIGNAL_MODES:
            raise ConfigError(
                f"traffic_signals.mode: expected one of {', '.join(SIGNAL_MODES)}, got {self.mode!r}"
            )
        check_range("traffic_signals.green_s", self.green_s, 1.0, 600.0)
        check_range("traffic_signals.yellow_s", self.yellow_s, 3.0, 6.0)
        check_range("traffic_signals.red_s", self.red_s, 1.0, 600.0)
        check_range("traffic_signals.offset_s", self.offset_s, 0.0, 3600.0)
        check_range("traffic_signals.flash_period_s", self.flash_period_s, 1.0, 1.2)
        check_range("traffic_signals.flash_on_fraction", self.flash_on_fraction, 0.5, 2.0 / 3.0)

    @property
    def cycle_s(self) -> float:
        return self.green_s + self.yellow_s + self.red_s


class SignalController:
    """The true state of the signals at any time; no randomness, so runs repeat exactly."""

    def __init__(self, config: SignalConfig, signal_ids: tuple[int, ...]) -> None:
        self.config = config
        self.signal_ids = tuple(signal_ids)

    def state(self, signal_id: int, t_s: float) -> LightState:
        """What ``signal_id`` shows at ``t_s``: its lit colour, or OFF (dark, or between flashes).

        Raises:
            ConfigError: ``signal_id`` is not one of the controller's signals.
        """
        if signal_id not in self.signal_ids:
            raise ConfigError(
                f"SignalController: expected a signal among {list(self.signal_ids)}, got {signal_id}"
            )
        c = self.config
        if c.mode == "dark":
            return LightState.OFF
        if c.mode in ("flashing_red", "flashing_yellow"):
            lit = math.fmod(t_s, c.flash_period_s) < c.flash_on_fraction * c.flash_period_s
            colour = LightState.RED if c.mode == "flashing_red" else LightState.YELLOW
            return colour if lit else LightState.OFF
        phase = math.fmod(t_s + c.offset_s, c.cycle_s)
        if phase < c.green_s:
            return LightState.GREEN
        if phase < c.green_s + c.yellow_s:
            return LightState.YELLOW
        return LightState.RED

    def must_stop(self, signal_id: int, t_s: float) -> bool:
        """True while crossing the stop line is a violation without a prior stop: red, or flashing red."""
        if self.config.mode == "flashing_red":
            return True
        return self.state(signal_id, t_s) is LightState.RED

    def stop_then_go(self) -> bool:
        """Flashing red: a stop sign, so crossing is legal after a full stop."""
        return self.config.mode == "flashing_red"
