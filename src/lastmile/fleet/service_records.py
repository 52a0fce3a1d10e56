"""The dispatcher's in-memory records of a shuttle and of a trip, and the clock they are stamped with."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from lastmile.fleet.scheduling import PlanItem, Visit

ACTIVE_RIDE_STATES = ("waiting", "assigned", "picked_up")
"""Ride states still held in memory (a ride leaves memory once dropped off or cancelled)."""


def now_us() -> int:
    return time.time_ns() // 1000


@dataclass(slots=True, kw_only=True)
class VehicleState:
    """A shuttle as the dispatcher knows it: its row in ``vehicles``, what it last reported, its plan."""

    id: str
    name: str
    capacity: int
    service: str = "out_of_service"
    x_m: float | None = None
    y_m: float | None = None
    yaw_rad: float | None = None
    speed_mps: float | None = None
    route_s_m: float | None = None
    behaviour: str | None = None
    health: str | None = None
    passengers: int = 0
    door: str | None = None
    hmi: dict[str, str] | None = None  # live only (not stored): what the HMI shows now
    last_status_us: int | None = None
    registered_us: int = 0
    connected: bool = False
    plan: list[Visit] = field(default_factory=list)


@dataclass(slots=True, kw_only=True)
class TripState:
    """One thing a shuttle must do at a stop (pick up, drop off, call for a timetable run, seat stop)."""

    id: int
    vehicle_id: str
    kind: str
    stop_id: str
    request_id: str | None
    run_id: str | None
    seats: int
    state: str

    def message(self) -> dict[str, Any]:
        """The trip as an ``assignment`` message carries it to the vehicle."""
        return {
            "id": self.id,
            "kind": self.kind,
            "stop_id": self.stop_id,
            "request_id": self.request_id,
            "run_id": self.run_id,
            "seats": self.seats,
        }

    def plan_item(self) -> PlanItem:
        """The trip as an entry of its vehicle's plan."""
        return PlanItem(
            trip_id=self.id, kind=self.kind, request_id=self.request_id, seats=self.seats, run_id=self.run_id
        )

    def row(self) -> dict[str, Any]:
        """The trip's new row in the ``trips`` table (its visit number is set by the plan's renumbering)."""
        return {
            "id": self.id,
            "vehicle_id": self.vehicle_id,
            "kind": self.kind,
            "stop_id": self.stop_id,
            "request_id": self.request_id,
            "run_id": self.run_id,
            "seats": self.seats,
            "visit": 0,
            "state": self.state,
            "created_us": now_us(),
            "done_us": None,
        }
