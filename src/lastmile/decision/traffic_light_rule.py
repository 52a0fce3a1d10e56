"""Traffic-light rule: where to stop for the signals on the route, from the traffic-light tracker's states.

At each signalised stop line ahead (within ``approach_m``) the heads of its signal are read from
:class:`~lastmile.core.traffic_light_messages.TrafficLightStates` and combined conservatively (red over
yellow over green). Then:

- red: stop at the line;
- yellow: stop if the shuttle can with comfortable braking, else go on. Comfortable is the braking the
  speed law will really apply: after one decision cycle it ramps in at a bounded jerk up to
  ``comfort_decel_mps2`` (:func:`comfortable_stop_m`); v^2 / 2d alone forgets the metres the ramp
  covers (at 5.5 m/s a 1.8 m/s^2 ramp at 1.5 m/s^3 takes 1.2 s and 6.2 m), and a stop judged
  comfortable that way ends near 3 m/s^2. The choice is kept until the light changes, so a stop once
  begun is finished, and a go is never turned into a late hard stop;
- green, or flashing yellow (proceed with caution): go;
- flashing red: a stop sign: stop at the line, stand ``full_stop_s``, then go;
- no established track of any of the signal's heads, or all of them unknown/off, within
  ``unknown_as_red_m`` of the line: treat as red (the map says a signal is there; not seeing it is no
  licence to drive through).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from lastmile.core.errors import ConfigError
from lastmile.core.traffic_light_messages import LightState, TrafficLightStates
from lastmile.hdmap.layers import RouteStopLine, SLayerDatabase

# What the rule concluded for a signal: the state it acts on.
RED, YELLOW, GREEN, FLASHING_RED, FLASHING_YELLOW, UNKNOWN = (
    "red",
    "yellow",
    "green",
    "flashing red",
    "flashing yellow",
    "unknown",
)


@dataclass(frozen=True, slots=True, kw_only=True)
class TrafficLightRuleConfig:
    """Parameters of :class:`TrafficLightRule`.

    Attributes:
        approach_m: signal stop lines closer than this (front bumper to line) are acted on.
        unknown_as_red_m: within this distance of the line a signal nobody sees counts as red.
        comfort_decel_mps2: the deceleration the shuttle may use to stop on yellow (standing
            passengers: Snow Lion's measured envelope, -1.83 m/s^2, well below a car's 3 m/s^2; the
            speed law's own comfortable braking is 1.8).
        brake_jerk_mps3: the jerk at which the speed law ramps its braking in (control's
            ``reference_jerk_mps3``, under Snow Lion's 1.84 m/s^3).
        reaction_s: time from the light seen to the braking begun: one decision cycle (10 Hz).
        full_stop_s: how long the shuttle stands at a flashing red before it goes.
        stop_before_line_m: where the front bumper stops, this far before the line.
        gap_floor_m: the gap left to the stop point is taken as at least this when the braking it
            needs is computed (no division by zero at or past the point).
        at_line_m: at a flashing red, the front within this of the stop point counts as at the line.
        stopped_mps: below this speed the shuttle counts as standing at the line.
    """

    approach_m: float = 60.0
    unknown_as_red_m: float = 40.0
    comfort_decel_mps2: float = 1.8
    brake_jerk_mps3: float = 1.5
    reaction_s: float = 0.1
    full_stop_s: float = 1.0
    stop_before_line_m: float = 0.5
    gap_floor_m: float = 0.05
    at_line_m: float = 3.0
    stopped_mps: float = 0.1

    def __post_init__(self) -> None:
        if not 0 < self.unknown_as_red_m <= self.approach_m:
            raise ConfigError(
                "TrafficLightRuleConfig: expected 0 < unknown_as_red_m <= approach_m, got "
                f"{self.unknown_as_red_m}, {self.approach_m}"
            )
        if self.comfort_decel_mps2 <= 0 or self.full_stop_s < 0 or self.stop_before_line_m < 0:
            raise ConfigError(
                "TrafficLightRuleConfig: expected comfort_decel_mps2 > 0, full_stop_s >= 0, "
                f"stop_before_line_m >= 0, got {self.comfort_decel_mps2}, {self.full_stop_s}, "
                f"{self.stop_before_line_m}"
            )
        if not (self.brake_jerk_mps3 > 0 and self.reaction_s >= 0):
            raise ConfigError(
                "TrafficLightRuleConfig: expected brake_jerk_mps3 > 0 and reaction_s >= 0, got "
                f"{self.brake_jerk_mps3}, {self.reaction_s}"
            )
        if self.gap_floor_m <= 0:
            raise ConfigError(f"TrafficLightRuleConfig.gap_floor_m: expected > 0, got {self.gap_floor_m}")


@dataclass(slots=True)
class _Approach:
    """What the rule keeps about the line it is approaching."""

    yellow_choice: str = ""  # "stop" or "go" once decided on a yellow
    stopped_since_s: float | None = None
    cleared: bool = False  # flashing red: full stop done


@dataclass
class TrafficLightRule:
    """Stop points for the signals of a route; ``step`` runs every decision cycle."""

    layers: SLayerDatabase
    config: TrafficLightRuleConfig = field(default_factory=TrafficLightRuleConfig)
    last_seen: str = ""
    _heads: dict[int, frozenset[str]] = field(default_factory=dict)
    _approach: dict[int, _Approach] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for rl in self.layers.signal_stop_lines:
            sig = rl.stop_line.signal_id
            assert sig is not None  # signal_stop_lines holds only signalised lines
            self._heads[rl.stop_line.id] = frozenset(h.light_id for h in self.layers.hdmap.signal(sig).heads)

    def step(
        self,
        t_s: float,
        front_s_m: float,
        speed_mps: float,
        lights: TrafficLightStates | None,
        ahead: Callable[[float, float], float],
    ) -> tuple[float | None, str]:
        """(front-bumper stop s or None, why) for the nearest signalised line ahead.

        Args:
            t_s: decision time (s).
            front_s_m: route s of the front bumper.
            speed_mps: the shuttle's speed.
            lights: the tracker's latest states (None: no tracker output, every signal is unknown).
            ahead: route distance from the front to an s (wrapping on a loop), as the FSM measures it.
        """
        best = self._nearest_line(front_s_m, ahead)
        # Forget lines no longer being approached, so the next pass starts afresh.
        active = best[1].stop_line.id if best is not None else None
        for line_id in [k for k in self._approach if k != active]:
            del self._approach[line_id]
        if best is None:
            self.last_seen = ""
            return None, ""
        dist, rl = best
        seen = self.signal_state(rl.stop_line.id, lights)
        self.last_seen = seen
        st = self._approach.setdefault(rl.stop_line.id, _Approach())
        c = self.config
        line = _LineApproach(
            t_s=t_s,
            speed_mps=speed_mps,
            dist_m=dist,
            stop_s_m=rl.s_m - c.stop_before_line_m,
            gap_m=dist - c.stop_before_line_m,
        )
        return _VERDICT_RULES[seen](c, st, line)

    def _nearest_line(
        self, front_s_m: float, ahead: Callable[[float, float], float]
    ) -> tuple[float, RouteStopLine] | None:
        """(distance from the front, line) of the nearest signalised line within the approach."""
        c = self.config
        best: tuple[float, RouteStopLine] | None = None
        for rl in self.layers.signal_stop_lines:
            d = ahead(rl.s_m, front_s_m)
            if -c.stop_before_line_m < d < c.approach_m and (best is None or d < best[0]):
                best = (d, rl)
        return best

    def signal_state(self, stop_line_id: int, lights: TrafficLightStates | None) -> str:
        """The state the rule acts on for the signal of ``stop_line_id`` (see the module docstring)."""
        heads = self._heads.get(stop_line_id, frozenset())
        if lights is None or not heads:
            return UNKNOWN
        seen: set[str] = set()
        for i, light_id in enumerate(lights.light_ids):
            if light_id not in heads:
                continue
            state, flashing = LightState(int(lights.states[i])), bool(lights.flashing[i])
            if flashing and state is LightState.RED:
                seen.add(FLASHING_RED)
            elif flashing and state is LightState.YELLOW:
                seen.add(FLASHING_YELLOW)
            elif state is not LightState.OFF:
                seen.add({LightState.RED: RED, LightState.YELLOW: YELLOW, LightState.GREEN: GREEN}[state])
        # Heads of one signal that disagree: act on the most restrictive.
        for verdict in (FLASHING_RED, RED, YELLOW, FLASHING_YELLOW, GREEN):
            if verdict in seen:
                return verdict
        return UNKNOWN


@dataclass(frozen=True, slots=True)
class _LineApproach:
    """The line being approached this cycle: when, how fast, how far, where to stop."""

    t_s: float
    speed_mps: float
    dist_m: float
    stop_s_m: float
    gap_m: float


_Verdict = tuple[float | None, str]


def _go(c: TrafficLightRuleConfig, st: _Approach, line: _LineApproach, seen: str) -> _Verdict:
    st.yellow_choice = ""
    return None, f"signal {seen}: go"


def _unknown(c: TrafficLightRuleConfig, st: _Approach, line: _LineApproach) -> _Verdict:
    if line.dist_m > c.unknown_as_red_m:
        return None, ""
    return line.stop_s_m, "signal expected but unknown: treat as red"


def comfortable_stop_m(speed_mps: float, c: TrafficLightRuleConfig, accel_mps2: float = 0.0) -> float:
    """Distance to stop from ``speed_mps`` braking comfortably as the speed law does it: ``reaction_s``
    at speed, the deceleration ramped in at ``brake_jerk_mps3`` up to ``comfort_decel_mps2``, then held.

    Ramping to D at jerk j takes D / j and covers v D / j - D^3 / (6 j^2), leaving v - D^2 / (2 j);
    a slow shuttle stops within the ramp, after sqrt(2 v / j) and 2/3 v of it.

    A shuttle accelerating (``accel_mps2`` > 0, its last command) first ramps that acceleration out
    at the same jerk: over a / j it covers v a / j + a^3 / (3 j^2) and gains a^2 / (2 j) of speed.
    Merging out of a bay at 0.52 m/s and 0.97 m/s^2 (snow seed 2), a hold for traffic from the rear
    placed at a steady speed's 0.34 m was braked for at -2.70 m/s^3; counting the acceleration it is
    1.28 m. A shuttle already braking is taken as steady (the stop errs long).

    The crosswalk rule's comfortable room stays at a steady speed: counted with the acceleration,
    a new unclassified track beside a crossing was ignored while the shuttle crept off its line,
    then yielded to once settled, with the front already past the line (clear seed 2, a 1.0 m/s^2
    a_nom: a crosswalk_yield violation)."""
    v, a, j = max(speed_mps, 0.0), max(accel_mps2, 0.0), c.brake_jerk_mps3
    reaction_m = v * c.reaction_s + 0.5 * a * c.reaction_s**2
    v += a * c.reaction_s
    ramp_out_m = v * a / j + a**3 / (3.0 * j * j)
    return reaction_m + ramp_out_m + _steady_stop_m(v + a * a / (2.0 * j), c)


def _steady_stop_m(v: float, c: TrafficLightRuleConfig) -> float:
    """Distance to stop from a steady ``v``, no reaction time: the ramp in to D, then D held."""
    j, d = c.brake_jerk_mps3, c.comfort_decel_mps2
    v_ramped = v - d * d / (2.0 * j)
    if v_ramped <= 0.0:
        return 2.0 / 3.0 * v * math.sqrt(2.0 * v / j)
    return v * d / j - d**3 / (6.0 * j * j) + v_ramped**2 / (2.0 * d)


def _can_stop(c: TrafficLightRuleConfig, line: _LineApproach) -> bool:
    return max(line.gap_m, c.gap_floor_m) >= comfortable_stop_m(line.speed_mps, c)


def _red(c: TrafficLightRuleConfig, st: _Approach, line: _LineApproach) -> _Verdict:
    if st.yellow_choice == "go" and not _can_stop(c, line):
        return None, "signal turned red after the yellow go: committed"
    return line.stop_s_m, "signal red"


def _yellow(c: TrafficLightRuleConfig, st: _Approach, line: _LineApproach) -> _Verdict:
    if not st.yellow_choice:
        st.yellow_choice = "stop" if _can_stop(c, line) else "go"
    if st.yellow_choice == "go":
        return None, "signal yellow: too close to stop comfortably, go"
    return line.stop_s_m, "signal yellow: stop"


def _flashing_red(c: TrafficLightRuleConfig, st: _Approach, line: _LineApproach) -> _Verdict:
    """A stop sign: stop at the line, stand ``full_stop_s``, then go."""
    if st.cleared:
        return None, "signal flashing red: stopped, go"
    if line.gap_m < c.at_line_m and line.speed_mps < c.stopped_mps:
        if st.stopped_since_s is None:
            st.stopped_since_s = line.t_s
        if line.t_s - st.stopped_since_s >= c.full_stop_s:
            st.cleared = True
            return None, "signal flashing red: stopped, go"
    else:
        st.stopped_since_s = None
    return line.stop_s_m, "signal flashing red: stop"


_VERDICT_RULES: dict[str, Callable[[TrafficLightRuleConfig, _Approach, _LineApproach], _Verdict]] = {
    GREEN: functools.partial(_go, seen=GREEN),
    FLASHING_YELLOW: functools.partial(_go, seen=FLASHING_YELLOW),
    UNKNOWN: _unknown,
    RED: _red,
    YELLOW: _yellow,
    FLASHING_RED: _flashing_red,
}
"""One rule per state the signal is read as (see the module docstring)."""
