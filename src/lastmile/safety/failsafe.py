"""Fail-safe arbitration: malfunction signals -> one latched SafetyDirective; the actuator-command gate."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.pedal_map import gem_brake_pedal
from lastmile.core.safety_messages import (
    FailSafeLevel,
    MalfunctionKind,
    MalfunctionSignal,
    MrmKind,
    SafetyDirective,
)
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand, TurnSignal
from lastmile.hdmap.layers import SLayerDatabase

# Causes that take away what a pull-over needs (a trusted pose near the curb, a view of the curb side,
# a working planner): with any of them active the manoeuvre stops in lane instead.
PULLOVER_BLOCKERS = frozenset(
    {
        MalfunctionKind.LOCALIZATION_INVALID,
        MalfunctionKind.LOCALIZATION_COVARIANCE,
        MalfunctionKind.GNSS_LOST,
        MalfunctionKind.OFF_MAP,
        MalfunctionKind.OFF_ROUTE,
        MalfunctionKind.MODULE_SILENT,
        MalfunctionKind.MODULE_EXCEPTION,
        MalfunctionKind.MODULE_UNHEALTHY,
        MalfunctionKind.SENSOR_SILENT,
        MalfunctionKind.SENSOR_FROZEN,
        MalfunctionKind.SENSOR_GARBAGE,
        MalfunctionKind.SENSOR_BLOCKAGE,
    }
)

# Levels above NONE, most severe first (precomputed: iterating an Enum is slow in a per-tick loop).
_LEVELS_DOWN = tuple(sorted((lv for lv in FailSafeLevel if lv != FailSafeLevel.NONE), reverse=True))

# Road types of the s-layer database where a shuttle may stop at the curb: normal road, bus bay.
_PULLOVER_ROAD_TYPES = (0, 3)


@dataclass(frozen=True, slots=True, kw_only=True)
class FailSafeConfig:
    """Arbitration and gate parameters.

    Attributes:
        clear_hold_us: per level, how long no signal of that level (or above) must have been seen before
            the latched level may drop below it (hysteresis against chattering monitors).
        estop_needs_reset: EMERGENCY_STOP stays latched until :meth:`FailSafeArbiter.operator_reset`
            (ISO 22737: a human confirms before automated driving resumes after an e-stop).
        default_speed_cap_mps: cap for SPEED_LIMIT signals that carry none (Snow Lion: 0.5 m/s).
        mrm_decel_mps2: comfortable deceleration of the minimal risk manoeuvre.
        max_decel_mps2: deceleration of the emergency stop (the vehicle's maximum).
        standstill_mps: below this the vehicle counts as stopped.
        speed_gain_1ps: the gate's proportional gain bringing speed down to the cap.
        pullover_lookahead_m: a curb must be reachable within this route distance past the comfortable
            stopping point for the MRM to pull over.
        pullover_max_curb_d_m: the curb must be at most this far right of the lane centre.
        pullover_min_ahead_m: a pull-over spot is at least this far ahead of the front: the planner's
            move to the curb (its ``pullover_m`` 20 m curve and ``settle_m`` 8 m run, laid for the rear
            axle 3.75 m behind the front) must fit in front of the shuttle.
    """

    clear_hold_us: dict[FailSafeLevel, int] = field(
        default_factory=lambda: {
            FailSafeLevel.SPEED_LIMIT: 2_000_000,
            FailSafeLevel.TAKEOVER_REQUEST: 3_000_000,
            FailSafeLevel.MINIMAL_RISK_MANOEUVRE: 5_000_000,
            FailSafeLevel.EMERGENCY_STOP: 5_000_000,
        }
    )
    estop_needs_reset: bool = True
    default_speed_cap_mps: float = 0.5
    mrm_decel_mps2: float = 1.0
    max_decel_mps2: float = 5.0
    standstill_mps: float = 0.05
    speed_gain_1ps: float = 1.0
    pullover_lookahead_m: float = 15.0
    pullover_max_curb_d_m: float = 4.0
    pullover_min_ahead_m: float = 30.0

    def __post_init__(self) -> None:
        missing = [
            lv.name for lv in FailSafeLevel if lv != FailSafeLevel.NONE and lv not in self.clear_hold_us
        ]
        if missing:
            raise ConfigError(
                f"FailSafeConfig.clear_hold_us: expected a hold for every level, missing {missing}"
            )
        for name in ("mrm_decel_mps2", "max_decel_mps2", "speed_gain_1ps"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"FailSafeConfig.{name}: expected > 0, got {getattr(self, name)}")
        if self.mrm_decel_mps2 > self.max_decel_mps2:
            raise ConfigError(
                f"FailSafeConfig: expected mrm_decel_mps2 <= max_decel_mps2, got "
                f"{self.mrm_decel_mps2} > {self.max_decel_mps2}"
            )


def signal_speed_cap_mps(signal: MalfunctionSignal, default_cap_mps: float) -> float | None:
    """The speed cap a signal asks for: its own, else ``default_cap_mps`` for a SPEED_LIMIT signal."""
    cap = signal.speed_cap_mps
    if cap is None and signal.level == FailSafeLevel.SPEED_LIMIT:
        cap = default_cap_mps
    return cap


def held_level(
    last_seen_us: Mapping[FailSafeLevel, int], now_us: int, clear_hold_us: Mapping[FailSafeLevel, int]
) -> FailSafeLevel:
    """The highest level whose last signal (at or above it) is younger than that level's clear hold."""
    for lv in _LEVELS_DOWN:
        seen = last_seen_us.get(lv)
        if seen is not None and now_us - seen < clear_hold_us[lv]:
            return lv
    return FailSafeLevel.NONE


def worst_first_reasons(active: Sequence[MalfunctionSignal]) -> tuple[FailSafeLevel, tuple[str, ...]]:
    """The top level among ``active`` and the reasons of its signals above NONE, most severe first."""
    if not active:
        return FailSafeLevel.NONE, ()
    top = max(s.level for s in active)
    if top == FailSafeLevel.NONE:
        return top, ()
    worst_first = sorted(active, key=lambda s: -int(s.level))
    return top, tuple(s.reason for s in worst_first if s.level > FailSafeLevel.NONE)


def reasons_at_or_below(
    reasons_by_level: Mapping[FailSafeLevel, tuple[str, ...]], level: FailSafeLevel
) -> tuple[str, ...]:
    """The last recorded reasons of the highest level at or below ``level`` (why it is held)."""
    for lv in _LEVELS_DOWN:
        if lv <= level and lv in reasons_by_level:
            return reasons_by_level[lv]
    return ()


def combined_speed_cap_mps(caps: Mapping[str, tuple[float, int]], level: FailSafeLevel) -> float | None:
    """The speed cap a directive at ``level`` carries: 0 at an e-stop, else the minimum of ``caps``
    (``(cap_mps, seen_us)`` per signal source and kind), none at NONE or without caps."""
    if level == FailSafeLevel.EMERGENCY_STOP:
        return 0.0
    if level == FailSafeLevel.NONE:
        return None
    return min((v[0] for v in caps.values()), default=None)


@dataclass(slots=True)
class EStopLatch:
    """EMERGENCY_STOP, once held, stays until the vehicle stands still and (when ``needs_reset``) the
    operator has confirmed; a reset given while the e-stop is still signalled is discarded."""

    latched: bool = False
    reset_requested: bool = False

    def request_reset(self) -> None:
        self.reset_requested = True

    def apply(self, held: FailSafeLevel, *, stopped: bool, needs_reset: bool) -> FailSafeLevel:
        """The level after the latch: ``held``, or EMERGENCY_STOP while the latch holds.

        Args:
            held: the level the signals hold now.
            stopped: the vehicle stands still.
            needs_reset: a release needs :meth:`request_reset` (``FailSafeConfig.estop_needs_reset``).
        """
        if held == FailSafeLevel.EMERGENCY_STOP:
            self.latched = True
            self.reset_requested = False
            return held
        if not self.latched:
            return held
        if stopped and (self.reset_requested or not needs_reset):
            self.latched = False
            self.reset_requested = False
            return held
        return FailSafeLevel.EMERGENCY_STOP


class FailSafeArbiter:
    """Picks the highest-priority response among the active signals and latches it.

    Escalation is immediate. A level is held while any signal at or above it was seen within its
    ``clear_hold_us``; then the level drops to the highest still held. EMERGENCY_STOP additionally
    needs standstill and (by default) :meth:`operator_reset`. Speed caps combine by minimum over the
    signals seen within the SPEED_LIMIT hold.

    Each ``update`` runs four steps, each testable alone: record the signals (:meth:`_record`), find
    the held level (:func:`held_level`, then :class:`EStopLatch`), follow a level change and choose
    the minimal risk manoeuvre once when it starts (:meth:`_enter_level`), and build the directive
    (:meth:`_directive`).
    """

    def __init__(self, config: FailSafeConfig | None = None, layers: SLayerDatabase | None = None) -> None:
        self.config = config or FailSafeConfig()
        self.layers = layers
        self._last_seen: dict[FailSafeLevel, int] = {}
        self._reasons: dict[FailSafeLevel, tuple[str, ...]] = {}
        self._caps: dict[str, tuple[float, int]] = {}
        self._level = FailSafeLevel.NONE
        self._since_us = 0
        self._latch = EStopLatch()
        self._mrm: MrmKind = MrmKind.NONE
        self._mrm_stop_s: float | None = None
        self.history: list[tuple[int, str, str]] = []
        """(stamp_us, from level, to level) of every level change."""

    @property
    def level(self) -> FailSafeLevel:
        return self._level

    def operator_reset(self) -> None:
        """The operator confirms the e-stop cause is gone (takes effect once the vehicle stands still)."""
        self._latch.request_reset()

    def update(
        self,
        now_us: int,
        signals: Iterable[MalfunctionSignal],
        *,
        speed_mps: float = 0.0,
        route_s_m: float | None = None,
    ) -> SafetyDirective:
        """Arbitrate the signals active at ``now_us``.

        Args:
            signals: every signal the monitors report now (a signal absent now is "cleared now").
            speed_mps: current speed estimate (standstill check, MRM stopping distance).
            route_s_m: front-bumper route s, for the MRM's stopping point and the pull-over search.
        """
        c = self.config
        blockers = self._record(now_us, list(signals))
        held = held_level(self._last_seen, now_us, c.clear_hold_us)
        held = self._latch.apply(
            held, stopped=abs(speed_mps) < c.standstill_mps, needs_reset=c.estop_needs_reset
        )
        self._enter_level(now_us, held)
        if held >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE and self._mrm == MrmKind.NONE:
            # Chosen once when the manoeuvre starts, so the stopping point does not run away.
            self._mrm, self._mrm_stop_s = self._plan_mrm(speed_mps, route_s_m, blockers)
        return self._directive(now_us, held)

    def _record(self, now_us: int, active: list[MalfunctionSignal]) -> bool:
        """Note when each level was last signalled, each signal's speed cap and the top level's reasons.

        Returns:
            Whether an active signal takes away what a pull-over needs (:data:`PULLOVER_BLOCKERS`).
        """
        blockers = False
        for sig in active:
            if sig.level == FailSafeLevel.NONE:
                continue
            if sig.kind in PULLOVER_BLOCKERS:
                blockers = True
            for covered in _LEVELS_DOWN:
                if covered <= sig.level:
                    self._last_seen[covered] = int(now_us)
            cap = signal_speed_cap_mps(sig, self.config.default_speed_cap_mps)
            if cap is not None:
                self._caps[sig.source + "/" + sig.kind.value] = (cap, int(now_us))
        top, reasons = worst_first_reasons(active)
        if top > FailSafeLevel.NONE:
            self._reasons[top] = reasons
        return blockers

    def _enter_level(self, now_us: int, held: FailSafeLevel) -> None:
        """Log a level change; a manoeuvre is chosen afresh on escalating to it and dropped below it."""
        if held == self._level:
            return
        self.history.append((int(now_us), self._level.name, held.name))
        if (
            held >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE > self._level
            or held < FailSafeLevel.MINIMAL_RISK_MANOEUVRE
        ):
            self._mrm, self._mrm_stop_s = MrmKind.NONE, None
        self._level = held
        self._since_us = int(now_us)

    def _directive(self, now_us: int, held: FailSafeLevel) -> SafetyDirective:
        """The directive for ``held``; speed caps older than the SPEED_LIMIT hold are forgotten first."""
        c = self.config
        cap_window = c.clear_hold_us[FailSafeLevel.SPEED_LIMIT]
        self._caps = {k: v for k, v in self._caps.items() if now_us - v[1] < cap_window}
        estop = held == FailSafeLevel.EMERGENCY_STOP
        mrm = held >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE
        return SafetyDirective(
            stamp=Stamp(int(now_us)),
            level=held,
            speed_cap_mps=combined_speed_cap_mps(self._caps, held),
            mrm=self._mrm if mrm else MrmKind.NONE,
            mrm_decel_mps2=c.max_decel_mps2 if estop else c.mrm_decel_mps2,
            mrm_stop_s_m=self._mrm_stop_s if mrm else None,
            emergency_stop=estop,
            takeover_request=held >= FailSafeLevel.TAKEOVER_REQUEST,
            since_us=self._since_us,
            reasons=reasons_at_or_below(self._reasons, held),
        )

    def _plan_mrm(
        self, speed_mps: float, route_s_m: float | None, blockers: bool
    ) -> tuple[MrmKind, float | None]:
        """Stop in lane at a comfortable deceleration, or pull over if a curb is within reach."""
        c = self.config
        if route_s_m is None:
            return MrmKind.STOP_IN_LANE, None
        stop_s = route_s_m + max(speed_mps, 0.0) ** 2 / (2.0 * c.mrm_decel_mps2)
        if blockers or self.layers is None:
            return MrmKind.STOP_IN_LANE, stop_s
        spot = self.pullover_s_m(max(stop_s, route_s_m + c.pullover_min_ahead_m))
        if spot is None:
            return MrmKind.STOP_IN_LANE, stop_s
        return MrmKind.PULL_OVER, spot

    def mrm_gap_m(self, front_s_m: float | None) -> float | None:
        """Route distance from the front bumper to the manoeuvre's stop point (None: no point or no
        front), the shorter way round on a closed route."""
        if self._mrm_stop_s is None or front_s_m is None:
            return None
        gap = self._mrm_stop_s - front_s_m
        route = self.layers.centerline if self.layers is not None else None
        if route is not None and route.closed:
            gap = route.ds_m(front_s_m, self._mrm_stop_s)
        return gap

    def pullover_s_m(self, from_s_m: float) -> float | None:
        """First route s in [from_s_m, from_s_m + lookahead] with a curb close by on a plain road or bay."""
        layers, c = self.layers, self.config
        if layers is None:
            return None
        s = np.arange(from_s_m, from_s_m + c.pullover_lookahead_m, layers.step_m)
        idx = layers.record_indices(s)
        curb = layers.curb_right_d_m[idx]
        ok = np.isin(layers.road_type[idx], _PULLOVER_ROAD_TYPES) & np.isfinite(curb)
        ok &= np.abs(np.where(np.isfinite(curb), curb, np.inf)) <= c.pullover_max_curb_d_m
        hit = np.flatnonzero(ok)
        return float(s[hit[0]]) if hit.size else None


def apply_safety_gate(
    command: ActuatorCommand,
    directive: SafetyDirective,
    speed_mps: float,
    config: FailSafeConfig | None = None,
    mrm_gap_m: float | None = None,
) -> ActuatorCommand:
    """The actuator-command gate: enforce the directive on the stack's command, whatever the stack did.

    - EMERGENCY_STOP: maximum deceleration, ``emergency_brake`` set, steering kept (stay in lane),
      door closed.
    - MINIMAL_RISK_MANOEUVRE with the front's distance to its stop point (``mrm_gap_m``): the stop
      point is enforced, not a fixed deceleration. Faster than the speed from which ``mrm_decel_mps2``
      still stops there, at least the braking that does (v^2 / 2 gap, up to the maximum); slower, the
      command may not accelerate past that speed (so a pull-over can still reach its spot); at the
      point, the brake is held. Steering is kept so the stack can pull over.
    - MINIMAL_RISK_MANOEUVRE without it: no acceleration; at least ``mrm_decel_mps2`` of braking while
      moving (a stronger brake in the command is kept), hold the brake at standstill.
    - any level with a speed cap: acceleration at most ``speed_gain * (cap - speed)``, floored at the
      comfortable MRM deceleration, so the vehicle settles on the cap without a hard brake.

    Returns:
        The command unchanged when nothing needs enforcing, else a new command with the same stamp.
    """
    c = config or FailSafeConfig()
    accel = command.accel_mps2
    door = command.door_open
    moving = abs(speed_mps) >= c.standstill_mps
    # An emergency stop or a minimal-risk manoeuvre puts the hazard lights on, whatever the stack asked.
    signal = (
        TurnSignal.HAZARD if directive.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE else command.turn_signal
    )
    if directive.level == FailSafeLevel.EMERGENCY_STOP:
        return dataclasses.replace(
            command,
            accel_mps2=-c.max_decel_mps2,
            emergency_brake=True,
            door_open=door and not moving,
            turn_signal=signal,
            throttle=0.0 if command.has_pedals else None,
            brake=1.0 if command.has_pedals else None,
        )
    if directive.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE:
        accel = min(accel, _mrm_limit_mps2(directive, speed_mps, moving, mrm_gap_m, c))
        door = door and not moving
    if directive.speed_cap_mps is not None:
        limit = max(c.speed_gain_1ps * (directive.speed_cap_mps - speed_mps), -c.mrm_decel_mps2)
        accel = min(accel, limit)
    if (
        math.isclose(accel, command.accel_mps2, abs_tol=0.0)
        and door == command.door_open
        and signal is command.turn_signal
    ):
        return command
    throttle, brake = gated_pedals(command, accel)
    return dataclasses.replace(
        command, accel_mps2=accel, door_open=door, turn_signal=signal, throttle=throttle, brake=brake
    )


def gated_pedals(command: ActuatorCommand, accel_mps2: float) -> tuple[float | None, float | None]:
    """Throttle and brake for a command whose acceleration the gate set to ``accel_mps2``.

    The stack's pedals are kept when the acceleration was not lowered (and None stays None: an
    acceleration interface). Lowered, the throttle is released (a positive limit then coasts: slower
    than the cap is on the safe side) and the brake is at least what GEM's map gives for the enforced
    deceleration.
    """
    if command.throttle is None or command.brake is None or accel_mps2 >= command.accel_mps2:
        return command.throttle, command.brake
    return 0.0, max(command.brake, gem_brake_pedal(-accel_mps2))


def _mrm_limit_mps2(
    directive: SafetyDirective, speed_mps: float, moving: bool, gap_m: float | None, c: FailSafeConfig
) -> float:
    """The most acceleration a minimal risk manoeuvre allows (see :func:`apply_safety_gate`)."""
    a_mrm = directive.mrm_decel_mps2
    if gap_m is None:
        return -a_mrm if moving else -c.mrm_decel_mps2
    if gap_m <= 0.05:
        return -a_mrm if not moving else -min(max(a_mrm, speed_mps**2 / 0.1), c.max_decel_mps2)
    v_allowed = math.sqrt(2.0 * a_mrm * gap_m)
    if speed_mps > v_allowed:
        return -min(speed_mps**2 / (2.0 * gap_m), c.max_decel_mps2)
    return max(c.speed_gain_1ps * (v_allowed - speed_mps), 0.0) if moving or gap_m > 0.5 else -a_mrm
