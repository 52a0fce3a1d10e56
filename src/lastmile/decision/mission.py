"""Mission: which stops the shuttle must serve, latched from stop buttons, seat buttons and dispatch."""

from __future__ import annotations

from dataclasses import dataclass, field

from lastmile.core.sensor_frames import StopCallFrame


@dataclass(slots=True)
class MissionManager:
    """Keeps the set of requested stops; a request is cleared when that stop has been served.

    Attributes:
        stop_order: stop ids in the order the loop passes them.
        serve_all: timetable mode, every stop is served on every loop (Snow Lion's fixed schedule).
    """

    stop_order: tuple[str, ...]
    serve_all: bool = False
    requested: set[str] = field(default_factory=set)
    served_count: dict[str, int] = field(default_factory=dict)

    def on_call(self, frame: StopCallFrame) -> None:
        if frame.stop_id in self.stop_order:
            self.requested.add(frame.stop_id)

    def wants(self, stop_id: str) -> bool:
        return self.serve_all or stop_id in self.requested

    def served(self, stop_id: str) -> None:
        self.requested.discard(stop_id)
        self.served_count[stop_id] = self.served_count.get(stop_id, 0) + 1
