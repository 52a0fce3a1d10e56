"""The one closed-loop engine: every single run, fleet run, sweep, test and benchmark steps this.

Each tick, in DESIGN.md's order: the world moves and its sensors deliver; the vehicle's safety sees
the inputs; the vehicle software ticks; the safety gates its command; the command actuates the vehicle
model; the referee judges and the operators act; then the callbacks, named after their phase, record
and report. Nothing else in the code base writes a tick loop.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, Generator, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from lastmile.core.safety_messages import SafetyDirective
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleSoftware
from lastmile.core.vehicle_messages import ActuatorCommand, BehaviourState, SafetyVerdict, StackOutput
from lastmile.sim.judge import Event


class World(Protocol):
    """What the loop steps on the world's side (the simulator, or a test rig), in phase order."""

    def advance_world(self, tick: int) -> None:
        """Move everything but the vehicle to ``tick``; sensors capture."""
        ...

    def sensor_frames(self, tick: int) -> list[SensorFrame]:
        """The frames whose latency has elapsed at ``tick`` (operator inputs included)."""
        ...

    def apply_command(self, command: ActuatorCommand | None) -> None:
        """Actuate the vehicle model for one tick (None: the vehicle's default brake)."""
        ...

    def referee(self, takeover_request: bool, reported_state: BehaviourState | None = None) -> None:
        """Judge the tick; operators act on what the vehicle shows."""
        ...

    def drain_events(self) -> list[Event]:
        """The referee's and operators' events since the last call."""
        ...


class Safety(Protocol):
    """What the loop asks of the vehicle's safety (``safety.vehicle_safety.VehicleSafety`` on a
    vehicle; a replay hands over recorded directives instead)."""

    directive: SafetyDirective | None
    """What the software is handed on its next tick."""

    def observe(self, now: Stamp, frames: Sequence[SensorFrame]) -> None:
        """The frames delivered at ``now``, before the software sees them."""
        ...

    def step(self, now: Stamp, output: StackOutput | None, failure: str = "") -> SafetyVerdict:
        """The software's output of this tick (None when it raised, with ``failure``), gated."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class TickRecord:
    """One tick as the callbacks see it.

    Attributes:
        frames: what the vehicle received this tick (sensors, V2I, operator inputs).
        output: what the vehicle software returned, None if it raised.
        failure: the exception text when it raised ("" otherwise).
        verdict: what the vehicle's safety made of it (directive, the command actuated).
        state: the behaviour state the vehicle reports (None before its first decision).
        events: the referee's and the operators' events of this tick.
        software_s: wall-clock seconds the software's tick took (for timing reports only).
    """

    tick: int
    now: Stamp
    t_s: float
    frames: tuple[SensorFrame, ...]
    output: StackOutput | None
    failure: str
    verdict: SafetyVerdict
    state: BehaviourState | None
    events: tuple[Event, ...]
    software_s: float


W = TypeVar("W", bound=World)


class LoopCallback:
    """Hooks of the loop's phases; override what you need (every hook does nothing by default)."""

    def on_start(self, loop: ClosedLoop[Any]) -> None:
        """Before the first tick."""

    def on_sense(self, tick: int, now: Stamp, frames: list[SensorFrame]) -> list[SensorFrame]:
        """The frames about to reach the vehicle; return them, changed or not (links, probes)."""
        return frames

    def on_tick(self, record: TickRecord) -> None:
        """After the tick: record, report, synchronise."""

    def on_end(self, loop: ClosedLoop[Any], ticks_run: int) -> None:
        """After the last tick, also when the run was interrupted."""


class ClosedLoop(Generic[W]):
    """The world, the vehicle software and the vehicle's safety, stepped tick by tick."""

    def __init__(
        self,
        world: W,
        software: VehicleSoftware,
        safety: Safety,
        tick_us: int,
        callbacks: Sequence[LoopCallback] = (),
    ) -> None:
        self.world = world
        self.software = software
        self.safety = safety
        self.tick_us = tick_us
        self.callbacks = list(callbacks)
        self.interrupted = False
        self.ticks_run = 0

    def step(self, tick: int) -> TickRecord:
        """One tick; returns what the callbacks were given."""
        now = Stamp(tick * self.tick_us)
        self.world.advance_world(tick)
        frames = self.world.sensor_frames(tick)
        for callback in self.callbacks:
            frames = callback.on_sense(tick, now, frames)
        self.safety.observe(now, frames)
        output, failure, software_s = self._software(now, frames)
        verdict = self.safety.step(now, output, failure)
        self.world.apply_command(verdict.command)
        state = output.decision.state if output is not None and output.decision is not None else None
        self.world.referee(verdict.takeover_request, state)
        record = TickRecord(
            tick=tick,
            now=now,
            t_s=tick * self.tick_us / 1e6,
            frames=tuple(frames),
            output=output,
            failure=failure,
            verdict=verdict,
            state=state,
            events=tuple(self.world.drain_events()),
            software_s=software_s,
        )
        for callback in self.callbacks:
            callback.on_tick(record)
        return record

    def _software(self, now: Stamp, frames: list[SensorFrame]) -> tuple[StackOutput | None, str, float]:
        t0 = time.perf_counter()
        try:
            output = self.software.tick(now, frames, self.safety.directive)
        except Exception as exc:  # a crashed process on a vehicle: the safety takes over this tick
            return None, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0
        return output, "", time.perf_counter() - t0

    def ticks(self, ticks: int, first_tick: int = 0) -> Generator[TickRecord, None, None]:
        """Step ``ticks`` ticks from ``first_tick`` (a replay starts where its recording does), yielding
        each tick's record (for tests that watch a run as it goes); the callbacks' ``on_end`` runs when
        the iteration ends, however it ends."""
        for callback in self.callbacks:
            callback.on_start(self)
        self.ticks_run = 0
        try:
            for k in range(ticks):
                record = self.step(first_tick + k)
                self.ticks_run = k + 1
                yield record
        finally:
            for callback in self.callbacks:
                callback.on_end(self, self.ticks_run)

    def run(self, ticks: int, stop: Callable[[], bool] | None = None) -> int:
        """Step ``ticks`` ticks; Ctrl-C, or ``stop()`` turning true between ticks, stops early with
        everything so far kept (``interrupted``).

        Returns:
            The number of ticks run.
        """
        steps = self.ticks(ticks)
        try:
            for _ in steps:
                if stop is not None and stop():
                    self.interrupted = True
                    break
        except KeyboardInterrupt:
            self.interrupted = True
        finally:
            steps.close()  # the callbacks' on_end now, not whenever the generator is collected
        return self.ticks_run


async def run_lockstep(
    loops: Sequence[ClosedLoop[Any]],
    ticks: int,
    before_tick: Callable[[int], None],
    after_tick: Callable[[int], Awaitable[bool]],
) -> int:
    """Step several loops in lockstep (a fleet in one world): ``before_tick``, every loop's tick, then
    ``after_tick``, which may end the run early by returning True. Returns the number of ticks run."""
    for loop in loops:
        for callback in loop.callbacks:
            callback.on_start(loop)
    done = 0
    try:
        for tick in range(ticks):
            before_tick(tick)
            for loop in loops:
                loop.step(tick)
            done = tick + 1
            if await after_tick(tick):
                break
    finally:
        for loop in loops:
            for callback in loop.callbacks:
                callback.on_end(loop, done)
    return done


def parked_ticks(world: World, ticks: Iterable[int]) -> Iterator[int]:
    """The world alone, with the vehicle parked (its default brake, no software): for tests of the
    world's own agents and sensors. Yields each tick after the world has advanced and before the
    vehicle model is actuated, so the caller reads the world's state at that point of the tick."""
    for tick in ticks:
        world.advance_world(tick)
        yield tick
        world.apply_command(None)
