"""What the API and the dashboards are shown of the dispatcher's records (plain JSON-ready dicts)."""

from __future__ import annotations

from typing import Any

from lastmile.fleet.service_records import VehicleState, now_us

RIDE_VIEW_FIELDS = (
    "id",
    "origin",
    "destination",
    "seats",
    "state",
    "vehicle_id",
    "created_us",
    "eta_pickup_us",
    "eta_dropoff_us",
    "picked_up_us",
    "dropped_off_us",
    "reason",
)


def ride_view(ride: dict[str, Any]) -> dict[str, Any]:
    """A ride as its rider sees it, with the seconds until pickup while it is assigned."""
    eta_s = None
    if ride["state"] == "assigned" and ride["eta_pickup_us"] is not None:
        eta_s = max(0.0, (ride["eta_pickup_us"] - now_us()) / 1e6)
    return {k: ride[k] for k in RIDE_VIEW_FIELDS} | {"eta_pickup_s": eta_s}


def vehicle_view(v: VehicleState) -> dict[str, Any]:
    """A shuttle as the operator sees it: service state, last report and plan."""
    return {
        "id": v.id,
        "name": v.name,
        "capacity": v.capacity,
        "service": v.service,
        "connected": v.connected,
        "x_m": v.x_m,
        "y_m": v.y_m,
        "yaw_rad": v.yaw_rad,
        "speed_mps": v.speed_mps,
        "route_s_m": v.route_s_m,
        "behaviour": v.behaviour,
        "health": v.health,
        "passengers": v.passengers,
        "door": v.door,
        "hmi": v.hmi,
        "last_status_us": v.last_status_us,
        "plan": [
            {"stop_id": visit.stop_id, "trips": [{"id": i.trip_id, "kind": i.kind} for i in visit.items]}
            for visit in v.plan
        ],
    }


def plan_message(v: VehicleState) -> dict[str, Any]:
    """The order in which the vehicle should serve its trips: one entry per stop visit."""
    return {
        "type": "plan",
        "visits": [
            {"stop_id": visit.stop_id, "trip_ids": [i.trip_id for i in visit.items]} for visit in v.plan
        ],
    }
