"""Re-run the stack on a recording's inputs and say where its output differs from what was recorded.

The recording names what produced it (the scenario and run configuration, ``RUN_METADATA``); a fresh
stack built from them gets, tick by tick, exactly the frames the loop delivered and the safety directive
in force, and its commands and behaviour states are compared with the recorded ones. A recording that
starts at t = 0 must match exactly (the run is deterministic); a 30 s window cut from a longer run
starts the stack mid-drive (no pose yet, no tracks), so its first seconds differ until it has caught up.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass

from lastmile.core.config import from_mapping
from lastmile.core.errors import ConfigError
from lastmile.core.safety_messages import SafetyDirective
from lastmile.core.vehicle_messages import ActuatorCommand, BehaviourDecision
from lastmile.recorder.replay import Recording
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.loop import ClosedLoop
from lastmile.runner.loop_callbacks import RUN_METADATA
from lastmile.runner.replay_world import RecordedSafety, RecordedWorld
from lastmile.runner.run_config import RunConfig
from lastmile.sim.scenario import Scenario

ACCEL_TOLERANCE_MPS2 = 1e-9
STEER_TOLERANCE_RAD = 1e-9
"""Commands closer than these are the same (the replay is deterministic: any real difference is larger)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class StackReplayDiff:
    """Where a fresh stack's output differs from the recorded one.

    Attributes:
        ticks: ticks replayed (every base tick from the recording's first to its last).
        compared: ticks with a recorded command to compare with.
        differing: of those, ticks whose command differs (acceleration, steering, door or e-brake).
        first_diff_us, last_diff_us: the first and last differing tick (None when none differ).
        max_accel_diff_mps2, max_steer_diff_rad: the largest differences.
        state_diffs: ticks whose behaviour state differs from the recorded decision's.
    """

    ticks: int
    compared: int
    differing: int
    first_diff_us: int | None
    last_diff_us: int | None
    max_accel_diff_mps2: float
    max_steer_diff_rad: float
    state_diffs: int

    @property
    def identical(self) -> bool:
        return self.differing == 0 and self.state_diffs == 0


def run_of(recording: Recording) -> tuple[Scenario, RunConfig]:
    """The scenario and run configuration a recording names.

    Raises:
        ConfigError: the recording has no :data:`RUN_METADATA` record (not from ``lastmile run``).
    """
    meta = dict(recording.metadata).get(RUN_METADATA)
    if meta is None or "scenario_toml" not in meta or "run_config_toml" not in meta:
        raise ConfigError(
            f"--through-stack: expected a recording of `lastmile run` with a {RUN_METADATA!r} metadata "
            f"record, got {recording.path} without one"
        )
    where = f"{recording.path}:{RUN_METADATA}"
    scenario = from_mapping(Scenario, tomllib.loads(meta["scenario_toml"]), where)
    config = from_mapping(RunConfig, tomllib.loads(meta["run_config_toml"]), where)
    return scenario, config


def _differs(a: ActuatorCommand, b: ActuatorCommand) -> tuple[bool, float, float]:
    da = abs(a.accel_mps2 - b.accel_mps2)
    ds = max(abs(a.steer_front_rad - b.steer_front_rad), abs(a.steer_rear_rad - b.steer_rear_rad))
    flags = a.door_open != b.door_open or a.emergency_brake != b.emergency_brake
    return flags or da > ACCEL_TOLERANCE_MPS2 or ds > STEER_TOLERANCE_RAD, da, ds


def replay_through_stack(recording: Recording) -> StackReplayDiff:
    """Feed a fresh stack the recorded inputs tick by tick and compare its output with the recording."""
    scenario, config = run_of(recording)
    stack = build_closed_loop(scenario, config).software
    by_tick: dict[int, dict[str, object]] = {}
    for m in recording.messages:
        if isinstance(m.message, ActuatorCommand | BehaviourDecision | SafetyDirective):
            by_tick.setdefault(m.log_time_us, {})[type(m.message).__name__] = m.message
    directives: dict[int, SafetyDirective] = {}
    for now, kinds in by_tick.items():
        directive = kinds.get("SafetyDirective")
        if isinstance(directive, SafetyDirective):
            directives[now] = directive
    world = RecordedWorld(recording, config.loop.tick_us)
    loop = ClosedLoop(world, stack, RecordedSafety(directives), config.loop.tick_us)
    state = None
    ticks = compared = differing = state_diffs = 0
    first = last = None
    max_da = max_ds = 0.0
    for record in loop.ticks(world.tick_count, first_tick=world.first_tick):
        now, out = record.now, record.output
        recorded = by_tick.get(int(now), {})
        ticks += 1
        cmd = recorded.get("ActuatorCommand")
        replayed = None if out is None else out.command
        if isinstance(cmd, ActuatorCommand) and (out is None or replayed is not None):
            compared += 1
            # A stack that raised where the recorded one commanded differs too.
            diff, da, ds = (True, 0.0, 0.0) if replayed is None else _differs(replayed, cmd)
            max_da, max_ds = max(max_da, da), max(max_ds, ds)
            if diff:
                differing += 1
                first = int(now) if first is None else first
                last = int(now)
        decision = recorded.get("BehaviourDecision")
        if isinstance(decision, BehaviourDecision):
            state = decision.state
        if state is not None and record.state is not None and record.state != state:
            state_diffs += 1
    return StackReplayDiff(
        ticks=ticks,
        compared=compared,
        differing=differing,
        first_diff_us=first,
        last_diff_us=last,
        max_accel_diff_mps2=max_da,
        max_steer_diff_rad=max_ds,
        state_diffs=state_diffs,
    )


def describe(diff: StackReplayDiff) -> str:
    """One line for the CLI: identical, or where and by how much the replayed output differs."""
    head = f"through the stack: {diff.ticks} ticks replayed, {diff.compared} recorded commands compared"
    if diff.identical:
        return f"{head}: identical commands and behaviour states"
    where = "; commands identical"
    if diff.first_diff_us is not None and diff.last_diff_us is not None:
        where = (
            f"; {diff.differing} differ, from {diff.first_diff_us / 1e6:.2f} s to "
            f"{diff.last_diff_us / 1e6:.2f} s (max |d accel| {diff.max_accel_diff_mps2:.3g} m/s², "
            f"max |d steer| {diff.max_steer_diff_rad:.3g} rad)"
        )
    return f"{head}{where}; behaviour state differs on {diff.state_diffs} ticks"
