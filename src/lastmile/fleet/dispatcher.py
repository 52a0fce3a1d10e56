"""The dispatcher: what riders and operators ask of the service (rides, commands, the timetable).

Its state, the rules shared by every operation and the durability contract are in ``service_core``;
what vehicles report is handled in ``vehicle_channel``. The server holds one ``Dispatcher``.
"""

from __future__ import annotations

from typing import Any

from fastapi import HTTPException, status
from sqlalchemy import Connection, insert, update

from lastmile.fleet import scheduling
from lastmile.fleet import storage as db
from lastmile.fleet.auth import Principal, new_token, token_hash
from lastmile.fleet.service_core import INSERT_EVENT
from lastmile.fleet.service_records import TripState, VehicleState, now_us
from lastmile.fleet.service_views import ride_view, vehicle_view
from lastmile.fleet.vehicle_channel import VehicleChannel

INSERT_RIDE = insert(db.ride_requests)


class Dispatcher(VehicleChannel):
    """Rides, operator commands and timetable runs, on top of the vehicle channel and the service core."""

    # ----------------------------------------------------------------------------------------- tokens
    async def issue_token(self, role: str, subject: str) -> str:
        tok = new_token(role)
        sha = token_hash(tok)

        def op(conn: Connection) -> None:
            conn.execute(
                insert(db.tokens).values(
                    sha256=sha, role=role, subject=subject, created_us=now_us(), revoked=False
                )
            )
            self._event(conn, "token_issued", None, None, role=role, subject=subject)

        await self.writer.submit(op)
        self.tokens.add(sha, role, subject)
        return tok

    # ----------------------------------------------------------------------------------------- rides
    async def create_ride(
        self, principal: Principal, origin: str, destination: str, seats: int, client_ref: str | None
    ) -> tuple[dict[str, Any], bool]:
        """A new ride (or the one ``client_ref`` already made): (view, created)."""
        self.stop_or_404(origin, "origin")
        self.stop_or_404(destination, "destination")
        if origin == destination:
            raise HTTPException(
                status.HTTP_422_UNPROCESSABLE_ENTITY,
                f"destination: expected a stop other than the origin, got {destination!r} for both",
            )
        key = (principal.subject, client_ref) if client_ref is not None else None
        if key is not None and key in self.by_ref:
            return self._replayed(self.ride_or_404(self.by_ref[key], principal), origin, destination, seats)
        ride: dict[str, Any] = {
            "id": self._ride_id(),
            "client_ref": client_ref,
            "rider": principal.subject,
            "origin": origin,
            "destination": destination,
            "seats": seats,
            "state": "waiting",
            "vehicle_id": None,
            "created_us": now_us(),
            "eta_pickup_us": None,
            "eta_dropoff_us": None,
            "picked_up_us": None,
            "dropped_off_us": None,
            "closed_us": None,
            "reason": "queued: no shuttle in service has free seats within the planning horizon",
        }
        if key is not None:
            self.by_ref[key] = ride["id"]
        new_trips, vehicle = self._assign(ride)
        if vehicle is None and not any(v.service == "in_service" for v in self.vehicles.values()):
            ride["reason"] = "queued: no shuttle is in service"
        row = {k: ride[k] for k in ride}
        rows = self._visit_rows(vehicle) if vehicle else []
        trip_rows = [t.row() for t in new_trips]

        event = {
            "stamp_us": row["created_us"],
            "kind": "ride_requested",
            "vehicle_id": row["vehicle_id"],
            "request_id": row["id"],
            "detail": {"origin": origin, "destination": destination},
        }

        def op(conn: Connection) -> None:
            conn.execute(INSERT_RIDE, row)
            conn.execute(insert(db.trips), trip_rows)
            self._renumber(conn, rows)
            conn.execute(INSERT_EVENT, event)

        self._remember(ride)
        try:
            # A queued ride touches no plan: two plain inserts the writer batches with others'.
            await self.writer.submit(
                op if trip_rows else db.InsertRows(((db.ride_requests, row), (db.events, event)))
            )
        except Exception:
            self._forget_failed(ride, new_trips)
            raise
        for t in new_trips:
            self.push(t.vehicle_id, {"type": "assignment", "trip": t.message()})
        self._touch()
        return ride_view(ride), True

    @staticmethod
    def _replayed(
        ride: dict[str, Any], origin: str, destination: str, seats: int
    ) -> tuple[dict[str, Any], bool]:
        """A retry with a rider's earlier ``client_ref``: the same ride if it asks the same, else 409
        (a key reused for another trip must not silently return the old ride)."""
        if (ride["origin"], ride["destination"], ride["seats"]) != (origin, destination, seats):
            raise HTTPException(
                status.HTTP_409_CONFLICT,
                f"client_ref {ride['client_ref']!r}: expected the same request as before "
                f"({ride['origin']}->{ride['destination']}, {ride['seats']} seats), "
                f"got {origin}->{destination}, {seats} seats; use a new client_ref for a new ride",
            )
        return ride_view(ride), False

    async def cancel_ride(self, principal: Principal, ride_id: str) -> dict[str, Any]:
        ride = self.ride_or_404(ride_id, principal)
        if ride["state"] not in ("waiting", "assigned"):
            raise HTTPException(
                status.HTTP_409_CONFLICT,
                f"ride {ride_id!r}: can only cancel a waiting or assigned ride, it is {ride['state']!r}",
            )
        cancelled = [t for t in self.trips.values() if t.request_id == ride_id]
        for t in cancelled:
            self._drop_from_plan(t)
        ride.update(state="cancelled", closed_us=now_us(), reason=f"cancelled by {principal.role}")
        self.rides.pop(ride_id, None)
        self.waiting.pop(ride_id, None)
        vids = {t.vehicle_id for t in cancelled}
        renumber = [r for vid in vids for r in self._visit_rows(self.vehicles[vid])]
        ids = [t.id for t in cancelled]
        snapshot = dict(ride)

        def op(conn: Connection) -> None:
            conn.execute(
                update(db.ride_requests)
                .where(db.ride_requests.c.id == ride_id)
                .values(state="cancelled", closed_us=snapshot["closed_us"], reason=snapshot["reason"])
            )
            if ids:
                conn.execute(update(db.trips).where(db.trips.c.id.in_(ids)).values(state="cancelled"))
                self._renumber(conn, renumber)
            self._event(conn, "ride_cancelled", snapshot["vehicle_id"], ride_id, by=principal.role)

        await self.writer.submit(op)
        for t in cancelled:
            self.push(t.vehicle_id, {"type": "cancel", "trip_id": t.id})
        await self._drain()
        self._touch()
        return ride_view(snapshot)

    # ----------------------------------------------------------------------------------------- vehicles
    async def register_vehicle(
        self, vehicle_id: str, name: str, capacity: int
    ) -> tuple[dict[str, Any], bool]:
        existing = self.vehicles.get(vehicle_id)
        if existing is not None:
            return vehicle_view(existing), False
        v = VehicleState(id=vehicle_id, name=name or vehicle_id, capacity=capacity, registered_us=now_us())
        row = {
            "id": v.id,
            "name": v.name,
            "capacity": v.capacity,
            "service": v.service,
            "passengers": 0,
            "registered_us": v.registered_us,
        }

        def op(conn: Connection) -> None:
            conn.execute(insert(db.vehicles).values(**row))
            self._event(conn, "vehicle_registered", vehicle_id, None, capacity=capacity)

        await self.writer.submit(op)
        self.vehicles[v.id] = v
        self._touch()
        return vehicle_view(v), True

    async def command(
        self, principal: Principal, vehicle_id: str, command: str, reason: str
    ) -> dict[str, Any]:
        v = self.vehicle_or_404(vehicle_id)
        transitions = {
            "start_service": ({"out_of_service", "suspended", "in_service"}, "in_service"),
            "suspend_service": ({"in_service", "suspended", "out_of_service"}, "suspended"),
            "emergency_stop": (
                {"out_of_service", "in_service", "suspended", "emergency_stop"},
                "emergency_stop",
            ),
            "release_emergency_stop": ({"emergency_stop"}, "suspended"),
        }
        allowed, target = transitions[command]
        if v.service not in allowed:
            raise HTTPException(
                status.HTTP_409_CONFLICT,
                f"vehicle {vehicle_id!r}: {command} needs service state in {sorted(allowed)}, "
                f"it is {v.service!r}",
            )
        previous = v.service
        v.service = target
        requeued: list[TripState] = []
        if target != "in_service":
            # Riders not yet on board go back to the queue, to be placed on another shuttle.
            for t in list(self.trips.values()):
                if t.vehicle_id != v.id or t.request_id is None:
                    continue
                ride = self.rides.get(t.request_id)
                if ride is not None and ride["state"] == "assigned":
                    requeued.append(t)
                    self._drop_from_plan(t)
            for t in requeued:
                ride = self.rides.get(t.request_id or "")
                if ride is not None and ride["state"] == "assigned":
                    ride.update(
                        state="waiting",
                        vehicle_id=None,
                        eta_pickup_us=None,
                        eta_dropoff_us=None,
                        reason=f"queued again: shuttle {v.id} {target.replace('_', ' ')}",
                    )
                    self._remember(ride)
        ids = [t.id for t in requeued]
        rides = sorted({t.request_id for t in requeued if t.request_id})
        reasons = {r: self.rides[r]["reason"] for r in rides}
        renumber = self._visit_rows(v)

        def op(conn: Connection) -> None:
            conn.execute(update(db.vehicles).where(db.vehicles.c.id == vehicle_id).values(service=target))
            if ids:
                conn.execute(update(db.trips).where(db.trips.c.id.in_(ids)).values(state="cancelled"))
                for rid in rides:
                    conn.execute(
                        update(db.ride_requests)
                        .where(db.ride_requests.c.id == rid)
                        .values(
                            state="waiting",
                            vehicle_id=None,
                            eta_pickup_us=None,
                            eta_dropoff_us=None,
                            reason=reasons[rid],
                        )
                    )
                self._renumber(conn, renumber)
            self._event(
                conn,
                "command",
                vehicle_id,
                None,
                command=command,
                by=principal.subject,
                previous=previous,
                reason=reason,
            )

        await self.writer.submit(op)
        self.push(vehicle_id, {"type": "command", "command": command, "service": target, "reason": reason})
        for t in requeued:
            self.push(vehicle_id, {"type": "cancel", "trip_id": t.id})
        await self._drain()
        self._touch()
        return vehicle_view(v)

    async def auto_dispatch_timetable(
        self, now_s: float, service_date: str, lead_s: float
    ) -> list[tuple[str, str]]:
        """Hand each timetable run departing within ``lead_s`` to the in-service shuttle with the
        fewest trips, once per service day; returns (run id, vehicle id) pairs handed out now."""
        first = {e["run_id"]: e["time_s"] for e in self.timetable if e["seq"] == 0}
        out: list[tuple[str, str]] = []
        for run_id in scheduling.due_runs(first, now_s, lead_s):
            if (service_date, run_id) in self.runs_dispatched or any(
                t.run_id == run_id for t in self.trips.values()
            ):
                continue
            candidates = [v for v in self.vehicles.values() if v.service == "in_service"]
            if not candidates:
                break  # tried again on the next tick, until the departure has passed
            load = {v.id: sum(len(visit.items) for visit in v.plan) for v in candidates}
            vehicle = min(candidates, key=lambda v: (load[v.id], v.id))
            await self.assign_timetable_run(vehicle.id, run_id, service_date)
            out.append((run_id, vehicle.id))
        return out

    async def assign_timetable_run(
        self, vehicle_id: str, run_id: str, service_date: str | None = None
    ) -> list[dict[str, Any]]:
        v = self.vehicle_or_404(vehicle_id)
        calls = [e for e in self.timetable if e["run_id"] == run_id]
        if not calls:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"unknown timetable run id {run_id!r}")
        if any(t.run_id == run_id for t in self.trips.values()):
            raise HTTPException(status.HTTP_409_CONFLICT, f"timetable run {run_id!r} is already assigned")
        s = self._vehicle_s(v)
        at = self.planner.first_ahead_m(s, calls[0]["stop_id"])
        new: list[TripState] = []
        prev = calls[0]["stop_id"]
        for k, call in enumerate(calls):
            if k > 0:
                at += self.route.stop_ahead_m(prev, call["stop_id"])
            trip = self._new_trip(v.id, "timetable", call["stop_id"], run_id=run_id)
            v.plan = self.planner.insert(v.plan, s, at, call["stop_id"], trip.plan_item())
            new.append(trip)
            prev = call["stop_id"]
        rows = [t.row() for t in new]
        renumber = self._visit_rows(v)

        def op(conn: Connection) -> None:
            conn.execute(insert(db.trips), rows)
            self._renumber(conn, renumber)
            self._event(conn, "timetable_run_assigned", vehicle_id, None, run_id=run_id, date=service_date)

        await self.writer.submit(op)
        if service_date is not None:
            self.runs_dispatched.add((service_date, run_id))
        for t in new:
            self.push(vehicle_id, {"type": "assignment", "trip": t.message()})
        self._touch()
        return [t.message() for t in new]
