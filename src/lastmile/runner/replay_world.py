"""A recording played back through the loop engine: the world delivers the recorded frames, the
safety hands over the recorded directives.

The replayed vehicle software gets, tick by tick, exactly what the recorded one got: the frames the
loop delivered at each tick and the safety directive in force. Its commands go nowhere (the recorded
run's vehicle has already moved), so the replay is open loop, stepped by the same engine as every run.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from lastmile.core.safety_messages import FailSafeLevel, SafetyDirective
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand, BehaviourState, SafetyVerdict, StackOutput
from lastmile.recorder.replay import Recording
from lastmile.sim.judge import Event


class RecordedWorld:
    """The loop's world for a replay: the recorded frames at the ticks they were delivered.

    Attributes:
        first_tick: the loop tick of the recording's first base tick.
        tick_count: how many base ticks the recording spans (every one, with or without frames: a stack
            counts its ticks to schedule its modules).
    """

    def __init__(self, recording: Recording, tick_us: int) -> None:
        self.tick_us = tick_us
        self._frames = {int(now): list(frames) for now, frames in recording.ticks(tick_us)}
        first_us = min(self._frames, default=0)
        self.first_tick = first_us // tick_us
        self.tick_count = len(self._frames)

    def advance_world(self, tick: int) -> None:
        """Nothing moves: the recorded frames are the world."""

    def sensor_frames(self, tick: int) -> list[SensorFrame]:
        return self._frames.get(tick * self.tick_us, [])

    def apply_command(self, command: ActuatorCommand | None) -> None:
        """Commands go nowhere: the recorded vehicle has already moved."""

    def referee(self, takeover_request: bool, reported_state: BehaviourState | None = None) -> None:
        """No referee: the replay compares outputs, it does not judge a drive."""

    def drain_events(self) -> list[Event]:
        return []


class RecordedSafety:
    """The loop's safety for a replay: the software's command passes ungated (the comparison is of the
    software's own output), and the directive recorded after each tick is the one it obeys next."""

    def __init__(self, directives: Mapping[int, SafetyDirective]) -> None:
        self._directives = directives
        self.directive: SafetyDirective | None = None

    def observe(self, now: Stamp, frames: Sequence[SensorFrame]) -> None:
        """The recorded directives already hold what the recorded safety made of these frames."""

    def step(self, now: Stamp, output: StackOutput | None, failure: str = "") -> SafetyVerdict:
        nominal = SafetyDirective(stamp=now, level=FailSafeLevel.NONE)
        verdict = SafetyVerdict(
            stamp=now,
            directive=self.directive or nominal,
            command=output.command if output is not None else None,
            stack_failed=output is None,
        )
        self.directive = self._directives.get(int(now), self.directive)
        return verdict
