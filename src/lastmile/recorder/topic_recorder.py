"""Which topics a recorder gets from one loop tick: the frames delivered to the stack and what it returned.

The black box (``black_box.py``) and the live view (``live_view.py``) record the same channels, so the
choice of topics lives here once.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterable
from typing import Any

from lastmile.core import frame_kinds
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.vehicle_messages import StackOutput

DETECTIONS_TOPIC = "/perception/detections"
"""The detections the tracker consumed (its Foxglove view is ``/viz/perception/detections``)."""


def sensor_topic(frame: SensorFrame) -> str:
    """The topic a sensor frame is recorded on."""
    return frame_kinds.frame_topic(frame)


class TopicRecorder(ABC):
    """Splits a tick into (topic, message) records for :meth:`record`."""

    def __init__(self) -> None:
        self._last_decision: object = None

    @abstractmethod
    def record(self, now_us: int, topic: str, message: Any) -> None:
        """Take one immutable core message seen at ``now_us``."""

    def record_frames(self, now_us: int, frames: Iterable[SensorFrame]) -> None:
        """The sensor frames delivered to the stack at ``now_us``."""
        for frame in frames:
            self.record(now_us, sensor_topic(frame), frame)

    def record_output(self, now_us: int, output: StackOutput) -> None:
        """What one stack tick returned: command, status, decision (when new), HMI, heartbeats, and on
        planning cycles the localization estimate, the detections the tracker consumed since the last
        one, the tracks and the planned trajectory."""
        if output.command is not None:
            self.record(now_us, "/stack/command", output.command)
        if output.status is not None:
            self.record(now_us, "/stack/status", output.status)
        if output.decision is not None and output.decision is not self._last_decision:
            # The stack hands back its current decision every tick; a new one is a new object.
            self._last_decision = output.decision
            self.record(now_us, "/decision/behaviour", output.decision)
        for hmi in output.hmi:
            self.record(now_us, "/stack/hmi", hmi)
        for beat in output.heartbeats:
            self.record(now_us, "/safety/heartbeat", beat)
        diag = output.diagnostics
        if diag is not None and diag.estimate is not None:
            self.record(now_us, "/localization/estimate", diag.estimate)
        for detections in output.detections or ():
            self.record(now_us, DETECTIONS_TOPIC, detections)
        if output.tracks is not None:
            self.record(now_us, "/tracking/tracks", output.tracks)
        if output.trajectory is not None:
            self.record(now_us, "/planning/trajectory", output.trajectory)
