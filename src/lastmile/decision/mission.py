"""Mission: which stops the shuttle must serve, latched from stop buttons, seat buttons and dispatch, and
the passengers' drop-off requests (Snow Lion's function button)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lastmile.core.sensor_frames import DropOffRequestFrame, StopCallFrame


@dataclass(slots=True)
class MissionManager:
    """Keeps the set of requested stops; a request is cleared when that stop has been served.

    Attributes:
        stop_order: stop ids in the order the loop passes them.
        serve_all: timetable mode, every stop is served on every loop (Snow Lion's fixed schedule).
        drop_off_since_s: when the pending drop-off request was first pressed (stack clock, seconds);
            None: none pending. Further presses before it is served are the same request (latched).
        drop_offs_served: drop-off requests served (the door cycle after the request completed).
    """

    stop_order: tuple[str, ...]
    serve_all: bool = False
    requested: set[str] = field(default_factory=set)
    served_count: dict[str, int] = field(default_factory=dict)
    drop_off_since_s: float | None = None
    drop_offs_served: int = 0

    def on_drop_off(self, frame: DropOffRequestFrame) -> None:
        if self.drop_off_since_s is None:
            self.drop_off_since_s = int(frame.stamp) / 1e6

    @property
    def drop_off_pending(self) -> bool:
        return self.drop_off_since_s is not None

    def drop_off_served(self) -> None:
        """A door cycle after the request has completed: the rider has had the door open to get off."""
        if self.drop_off_since_s is not None:
            self.drop_off_since_s = None
            self.drop_offs_served += 1

    def on_call(self, frame: StopCallFrame) -> None:
        if frame.stop_id in self.stop_order:
            self.requested.add(frame.stop_id)

    def wants(self, stop_id: str) -> bool:
        return self.serve_all or stop_id in self.requested

    def served(self, stop_id: str) -> None:
        self.requested.discard(stop_id)
        self.served_count[stop_id] = self.served_count.get(stop_id, 0) + 1
