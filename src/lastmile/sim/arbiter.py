"""Ground-truth arrival order at all-way stops, shared by every simulated vehicle and the shuttle."""

from __future__ import annotations

from dataclasses import dataclass, field

EGO_ID = 0
"""The shuttle's id in the arbiter and the judge (agents count from 1)."""


@dataclass(slots=True)
class AllWayStopArbiter:
    """First come, first served: vehicles register when stopped at a line and leave when they enter.

    A simulated car may go once it is the earliest waiting vehicle, has waited ``min_wait_s`` and the
    intersection box is empty; the shuttle is not commanded by this, only judged against it.
    """

    min_wait_s: float = 1.0
    queue: dict[int, tuple[float, int]] = field(default_factory=dict)
    box_occupied_by: set[int] = field(default_factory=set)

    def arrive(self, vehicle_id: int, stop_line_id: int, t_s: float) -> None:
        self.queue.setdefault(vehicle_id, (t_s, stop_line_id))

    def earlier_than(self, vehicle_id: int) -> list[int]:
        """Vehicles still waiting that arrived before ``vehicle_id`` (or all waiting, if it never arrived)."""
        mine = self.queue.get(vehicle_id)
        if mine is None:
            return [v for v in self.queue if v != vehicle_id]
        # A tie within 0.2 s is a tie: neither owes the other, as human drivers treat it.
        return [v for v, (t, _) in self.queue.items() if v != vehicle_id and t < mine[0] - 0.2]

    def may_go(self, vehicle_id: int, t_s: float) -> bool:
        mine = self.queue.get(vehicle_id)
        if mine is None or t_s - mine[0] < self.min_wait_s:
            return False
        if self.box_occupied_by - {vehicle_id}:
            return False
        earliest = min(self.queue.items(), key=lambda kv: (kv[1][0], kv[0]))[0]
        return earliest == vehicle_id or not self.earlier_than(vehicle_id)

    def enter(self, vehicle_id: int) -> None:
        self.queue.pop(vehicle_id, None)
