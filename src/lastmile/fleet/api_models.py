"""Request and response bodies of the dispatch API (pydantic: validated, and documented in OpenAPI)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from lastmile.fleet.scheduling import CAPACITY_SEATS

StopId = Field(min_length=1, max_length=16, pattern=r"^[A-Za-z0-9_-]+$")
VehicleId = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class RideRequestIn(Strict):
    origin: str = StopId
    destination: str = StopId
    seats: int = Field(default=1, ge=1, le=CAPACITY_SEATS)
    client_ref: str | None = Field(
        default=None,
        min_length=1,
        max_length=64,
        description="Idempotency key: a retry returns the same ride.",
    )


class RideOut(BaseModel):
    id: str
    origin: str
    destination: str
    seats: int
    state: Literal["waiting", "assigned", "picked_up", "dropped_off", "cancelled"]
    vehicle_id: str | None
    created_us: int
    eta_pickup_us: int | None = Field(
        description="Wall-clock microseconds since the epoch; None while queued."
    )
    eta_dropoff_us: int | None
    eta_pickup_s: float | None = Field(description="Seconds from now until the pick-up; None while queued.")
    picked_up_us: int | None
    dropped_off_us: int | None
    reason: str | None


class RidePage(BaseModel):
    """A page of the ride log: ``total`` rides match the filters, ``rides`` are those from ``offset``."""

    total: int
    offset: int
    limit: int
    rides: list[RideOut]


class VehicleIn(Strict):
    id: str = VehicleId
    name: str = Field(default="", max_length=128)
    capacity: int = Field(default=CAPACITY_SEATS, ge=1, le=CAPACITY_SEATS)


class VehicleOut(BaseModel):
    id: str
    name: str
    capacity: int
    service: str
    connected: bool
    x_m: float | None
    y_m: float | None
    yaw_rad: float | None
    speed_mps: float | None
    route_s_m: float | None
    behaviour: str | None
    health: str | None
    passengers: int
    door: str | None
    last_status_us: int | None
    plan: list[dict[str, object]]
    hmi: dict[str, str] | None = None


class PresenceIn(Strict):
    """An infrastructure node's report (NUS crossing camera): pedestrians on a crossing or not.

    ``crosswalk`` is the crossing's index in the HD map; ``captured_us`` the node's capture time in its
    own clock (microseconds), passed through to the vehicles unchanged.
    """

    node_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    crosswalk: int = Field(ge=0, le=10_000)
    present: bool
    captured_us: int = Field(ge=0)


class CommandIn(Strict):
    command: Literal["start_service", "suspend_service", "emergency_stop", "release_emergency_stop"]
    reason: str = Field(default="", max_length=256)


class TimetableRunIn(Strict):
    run_id: str = Field(min_length=1, max_length=32)


class TokenIn(Strict):
    role: Literal["rider", "operator", "vehicle", "infrastructure"]
    subject: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.*-]+$")


class TokenOut(BaseModel):
    token: str
    role: str
    subject: str


class StopOut(BaseModel):
    id: str
    name: str
    x_m: float
    y_m: float
    route_s_m: float
    waiting: int


class TimetableOut(BaseModel):
    run_id: str
    shift: str
    seq: int
    stop_id: str
    time_s: float
    clock: str


class EventOut(BaseModel):
    id: int
    stamp_us: int
    kind: str
    vehicle_id: str | None
    request_id: str | None
    detail: dict[str, object] | None


class RunOut(BaseModel):
    name: str
    files: list[str]
    bytes: int
