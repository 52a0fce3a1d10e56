"""Signal controller: what every mapped traffic signal shows at time t (fixed-time cycle or flashing).

A fixed-time controller runs green -> yellow -> red -> green; the flashing modes are what a signal
falls back to at night or on a fault: flashing red (drivers treat it as a stop sign) or flashing
yellow (proceed with caution). Flashing follows the MUTCD: 50 to 60 flashes a minute, lit between
half and two thirds of each cycle.

Signals share one fixed-time plan with two phases (``signal_phases``): at each signalised junction the
approaches along one axis run the main phase; the approaches crossing them (more than 45 degrees off
that axis) get the cross phase, green only inside the main phase's red, after an all-red clearance, so
two conflicting approaches never show green together (the campus's one crossing has a single axis: both
its directions run the main phase).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.config import check_range
from lastmile.core.errors import ConfigError
from lastmile.core.traffic_light_messages import LightState
from lastmile.hdmap.model import HDMap

SIGNAL_MODES = ("cycle", "flashing_red", "flashing_yellow", "dark")
ALL_RED_S = 1.0  # red clearance between the two phases: ITE's change interval recommends 1-2 s
JUNCTION_REACH_M = 60.0  # stop lines this close to another of a group are one junction's approaches
CROSSING_AXIS_RAD = math.pi / 4  # an approach more than this off the junction's main axis crosses it
MIN_CROSS_GREEN_S = 1.0


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

    def __init__(
        self, config: SignalConfig, signal_ids: tuple[int, ...], cross_ids: frozenset[int] = frozenset()
    ) -> None:
        """``cross_ids``: the signals that run the cross phase (``signal_phases``).

        Raises:
            ConfigError: a cross phase with no room in the main phase's red for its green, yellow and
                both all-red clearances.
        """
        self.config = config
        self.signal_ids = tuple(signal_ids)
        self.cross_ids = frozenset(cross_ids)
        room = config.red_s - config.yellow_s - 2 * ALL_RED_S
        if self.cross_ids and config.mode == "cycle" and room < MIN_CROSS_GREEN_S:
            raise ConfigError(
                f"traffic_signals.red_s: the map has crossing approaches, whose green, yellow and two "
                f"{ALL_RED_S:g} s all-red clearances fit in the main phase's red; expected at least "
                f"{config.yellow_s + 2 * ALL_RED_S + MIN_CROSS_GREEN_S:g} s, got {config.red_s:g}"
            )

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
        if signal_id in self.cross_ids:
            # Green from the main phase's red plus the clearance, to its end less yellow and clearance.
            phase -= c.green_s + c.yellow_s + ALL_RED_S
            green_s = c.red_s - c.yellow_s - 2 * ALL_RED_S
            if 0.0 <= phase < green_s:
                return LightState.GREEN
            if 0.0 <= phase - green_s < c.yellow_s:
                return LightState.YELLOW
            return LightState.RED
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


def signal_phases(hdmap: HDMap) -> frozenset[int]:
    """The signals of ``hdmap`` that run the cross phase.

    Signals whose stop lines lie within JUNCTION_REACH_M of one another (chained) are one junction; its
    main axis is the approach heading of its lowest-id signal, and every approach more than
    CROSSING_AXIS_RAD off that axis (either direction along it counts as on it) crosses it.
    """
    lines = {sl.id: sl for sl in hdmap.stop_lines}
    signals = sorted(hdmap.signals, key=lambda sig: sig.id)
    mids = [np.asarray(lines[sig.stop_line_id].line, dtype=float).mean(axis=0) for sig in signals]
    headings = []
    for sig in signals:
        centre = hdmap.lanelets[sig.lanelet_id].centerline
        headings.append(centre.heading_at(centre.length_m))
    group = list(range(len(signals)))  # union-find over "within reach"

    def root(i: int) -> int:
        while group[i] != i:
            i = group[i]
        return i

    for i in range(len(signals)):
        for j in range(i):
            if float(np.hypot(*(mids[i] - mids[j]))) <= JUNCTION_REACH_M:
                a, b = root(i), root(j)
                group[max(a, b)] = min(a, b)  # the root stays the group's lowest id
    cross = set()
    for i, sig in enumerate(signals):
        axis = headings[root(i)]
        off = abs(math.remainder(headings[i] - axis, math.pi))
        if off > CROSSING_AXIS_RAD:
            cross.add(sig.id)
    return frozenset(cross)
