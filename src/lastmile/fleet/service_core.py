"""The dispatcher's state and the rules every operation shares: placing a ride, draining the queue.

It runs on the server's event loop, so its state needs no locks. Every change is applied in memory,
queued to the group-committing writer, and only acknowledged (to the HTTP caller, or pushed to a
vehicle) after the commit: what anyone has been told is in the database. On start it rebuilds all of
its state from the database (``service_load``), which is what makes a restart lose nothing.

The operations are in two layers above this one: what vehicles report (``vehicle_channel``) and what
riders and operators ask for (``dispatcher``).
"""

from __future__ import annotations

import asyncio
import itertools
import uuid
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from fastapi import HTTPException, status
from sqlalchemy import Connection, Engine, bindparam, insert, select, update

from lastmile.fleet import storage as db
from lastmile.fleet.auth import Principal, TokenBook
from lastmile.fleet.scheduling import CAPACITY_SEATS, LoopRoute, Planner, Visit
from lastmile.fleet.service_load import load_service
from lastmile.fleet.service_records import TripState, VehicleState, now_us
from lastmile.fleet.service_views import plan_message, ride_view, vehicle_view

INSERT_EVENT = insert(db.events)
DRAIN_BATCH = 50  # queued rides retried per change of a plan; bounds the work one event can cause


class ServiceCore:
    """Service state and the shared rules. ``push`` sends a JSON message to a connected vehicle (set by
    the server)."""

    def __init__(self, engine: Engine, writer: db.Writer, route: LoopRoute, planner: Planner) -> None:
        self.engine = engine
        self.writer = writer
        self.route = route
        self.planner = planner
        self.tokens = TokenBook()
        self.vehicles: dict[str, VehicleState] = {}
        self.rides: dict[str, dict[str, Any]] = {}
        self.by_ref: dict[tuple[str, str], str] = {}  # (rider, client_ref) -> ride id
        self.waiting: OrderedDict[str, None] = OrderedDict()
        self.trips: dict[int, TripState] = {}
        self.timetable: list[dict[str, Any]] = []
        self._next_trip = 1
        self.push: Callable[[str, dict[str, Any]], None] = lambda vid, msg: None
        # Newest report of each infrastructure node (live only: a presence report is stale in a second).
        self.presence: dict[str, dict[str, Any]] = {}
        self.changed = asyncio.Event()
        self._id_prefix = uuid.uuid4().hex[:16]
        self._id_counter = 0
        self._onboard_memo: dict[str, tuple[list[Visit], int]] = {}
        self._plan_sent: dict[str, list[Visit]] = {}
        self.runs_dispatched: set[tuple[str, str]] = set()  # (service date, run id) handed out by the clock

    # ----------------------------------------------------------------------------------------- loading
    def load(self) -> dict[str, str]:
        """Create tables, seed what is empty, rebuild memory; returns tokens created now (role -> token)."""
        loaded = load_service(self.engine, self.route, self.planner)
        for sha, role, subject in loaded.tokens:
            self.tokens.add(sha, role, subject)
        self.timetable = loaded.timetable
        self.vehicles = loaded.vehicles
        for ride in loaded.rides:
            self._remember(ride)
        self.by_ref = loaded.by_ref
        self.trips = loaded.trips
        self._next_trip = loaded.next_trip
        self.runs_dispatched = loaded.runs_dispatched
        return loaded.created_tokens

    def _remember(self, ride: dict[str, Any]) -> None:
        self.rides[ride["id"]] = ride
        if ride["state"] == "waiting":
            self.waiting[ride["id"]] = None
        else:
            self.waiting.pop(ride["id"], None)

    # ----------------------------------------------------------------------------------------- helpers
    def stop_or_404(self, stop_id: str, what: str) -> None:
        if stop_id not in self.route.stops:
            raise HTTPException(
                status.HTTP_404_NOT_FOUND,
                f"{what}: unknown stop id {stop_id!r}, expected one of {list(self.route.order)}",
            )

    def vehicle_or_404(self, vehicle_id: str) -> VehicleState:
        vehicle = self.vehicles.get(vehicle_id)
        if vehicle is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"unknown vehicle id {vehicle_id!r}")
        return vehicle

    def ride_or_404(self, ride_id: str, principal: Principal) -> dict[str, Any]:
        ride = self.rides.get(ride_id)
        if ride is None:
            with self.engine.connect() as conn:
                row = conn.execute(select(db.ride_requests).where(db.ride_requests.c.id == ride_id)).first()
            if row is None:
                raise HTTPException(status.HTTP_404_NOT_FOUND, f"unknown ride id {ride_id!r}")
            ride = dict(row._mapping)
        if principal.role == "rider" and ride["rider"] != principal.subject:
            raise HTTPException(status.HTTP_403_FORBIDDEN, f"ride {ride_id!r} belongs to another rider")
        return ride

    def _event(
        self, conn: Connection, kind: str, vehicle_id: str | None, request_id: str | None, **detail: Any
    ) -> None:
        conn.execute(
            INSERT_EVENT,
            {
                "stamp_us": now_us(),
                "kind": kind,
                "vehicle_id": vehicle_id,
                "request_id": request_id,
                "detail": detail or None,
            },
        )

    def _vehicle_s(self, v: VehicleState) -> float:
        if v.route_s_m is not None:
            return v.route_s_m
        # Never reported: assume it starts at the first stop of the loop (the depot side).
        return self.route.stops[self.route.order[0]].route_s_m

    def _visit_rows(self, v: VehicleState) -> list[dict[str, int]]:
        return [{"tid": item.trip_id, "visit": k} for k, visit in enumerate(v.plan) for item in visit.items]

    def _touch(self) -> None:
        """Something changed: wake the dashboards, and tell each vehicle whose plan changed its new
        plan (after the assignments it refers to, which were pushed before this is called)."""
        self.changed.set()
        for v in self.vehicles.values():
            if self._plan_sent.get(v.id) is not v.plan:
                self._plan_sent[v.id] = v.plan
                self.push(v.id, plan_message(v))

    def _ride_id(self) -> str:
        """A random per-process prefix and a counter: unique across restarts without a system call per
        ride (``uuid4`` reads the OS's entropy each time, 75-400 us on this shared machine)."""
        self._id_counter += 1
        return f"{self._id_prefix}{self._id_counter:010x}"

    def _forget_failed(self, ride: dict[str, Any], new_trips: list[TripState]) -> None:
        self.rides.pop(ride["id"], None)
        self.waiting.pop(ride["id"], None)
        if ride.get("client_ref"):
            self.by_ref.pop((ride["rider"], ride["client_ref"]), None)
        for t in new_trips:
            self._drop_from_plan(t)

    @staticmethod
    def _renumber(conn: Connection, rows: list[dict[str, int]]) -> None:
        if rows:
            conn.execute(
                update(db.trips).where(db.trips.c.id == bindparam("tid")).values(visit=bindparam("visit")),
                rows,
            )

    def _new_trip(self, vehicle_id: str, kind: str, stop_id: str, **kw: Any) -> TripState:
        trip = TripState(
            id=self._next_trip,
            vehicle_id=vehicle_id,
            kind=kind,
            stop_id=stop_id,
            request_id=kw.get("request_id"),
            run_id=kw.get("run_id"),
            seats=kw.get("seats", 0),
            state="pending",
        )
        self._next_trip += 1
        self.trips[trip.id] = trip
        return trip

    def _assign(self, ride: dict[str, Any]) -> tuple[list[TripState], VehicleState | None]:
        """Insert ``ride`` into the best vehicle's plan (memory only); updates ``ride`` in place."""
        best = None
        for v in self.vehicles.values():
            if v.service != "in_service":
                continue
            ins = self.planner.best_insertion(
                v.id,
                v.plan,
                self._vehicle_s(v),
                self._onboard(v),
                min(v.capacity, CAPACITY_SEATS),
                ride["origin"],
                ride["destination"],
                ride["seats"],
            )
            if ins is not None and (best is None or ins.cost_s < best.cost_s):
                best = ins
        if best is None:
            return [], None
        v = self.vehicles[best.vehicle_id]
        s = self._vehicle_s(v)
        pick = self._new_trip(v.id, "pickup", ride["origin"], request_id=ride["id"], seats=ride["seats"])
        drop = self._new_trip(
            v.id, "dropoff", ride["destination"], request_id=ride["id"], seats=ride["seats"]
        )
        plan = self.planner.insert(v.plan, s, best.pickup_at_m, ride["origin"], pick.plan_item())
        v.plan = self.planner.insert(plan, s, best.dropoff_at_m, ride["destination"], drop.plan_item())
        t = now_us()
        ride.update(
            state="assigned",
            vehicle_id=v.id,
            eta_pickup_us=t + int(best.eta_pickup_s * 1e6),
            eta_dropoff_us=t + int(best.eta_dropoff_s * 1e6),
            reason=None,
        )
        return [pick, drop], v

    def _onboard(self, v: VehicleState) -> int:
        """Seats taken now: the larger of what the vehicle reports and what our own plan accounts for.

        Memoised on the plan's identity: a ride is picked up or dropped only through a change of plan.
        """
        hit = self._onboard_memo.get(v.id)
        if hit is not None and hit[0] is v.plan:
            return max(v.passengers, hit[1])
        planned = sum(
            self.rides[i.request_id]["seats"]
            for visit in v.plan
            for i in visit.items
            if i.kind == "dropoff"
            and i.request_id in self.rides
            and self.rides[i.request_id]["state"] == "picked_up"
        )
        self._onboard_memo[v.id] = (v.plan, planned)
        return max(v.passengers, planned)

    def _drop_from_plan(self, trip: TripState) -> None:
        self.trips.pop(trip.id, None)
        v = self.vehicles.get(trip.vehicle_id)
        if v is None:
            return
        for visit in v.plan:
            visit.items = [i for i in visit.items if i.trip_id != trip.id]
        v.plan = [visit for visit in v.plan if visit.items]

    async def _drain(self) -> None:
        """Try to place the oldest queued rides now that a plan has room."""
        if not self.waiting:
            return
        placed: list[tuple[dict[str, Any], list[TripState]]] = []
        for ride_id in list(self.waiting)[:DRAIN_BATCH]:
            ride = self.rides[ride_id]
            new_trips, vehicle = self._assign(ride)
            if vehicle is not None:
                self.waiting.pop(ride_id, None)
                placed.append((ride, new_trips))
        if not placed:
            return
        vids = {t.vehicle_id for _, ts in placed for t in ts}
        renumber = [r for vid in vids for r in self._visit_rows(self.vehicles[vid])]
        trip_rows = [t.row() for _, ts in placed for t in ts]
        updates = [
            {
                "rid": r["id"],
                "vid": r["vehicle_id"],
                "ep": r["eta_pickup_us"],
                "ed": r["eta_dropoff_us"],
            }
            for r, _ in placed
        ]

        def op(conn: Connection) -> None:
            conn.execute(
                update(db.ride_requests)
                .where(db.ride_requests.c.id == bindparam("rid"))
                .values(
                    state="assigned",
                    vehicle_id=bindparam("vid"),
                    eta_pickup_us=bindparam("ep"),
                    eta_dropoff_us=bindparam("ed"),
                    reason=None,
                ),
                updates,
            )
            conn.execute(insert(db.trips), trip_rows)
            self._renumber(conn, renumber)
            for u in updates:
                self._event(conn, "ride_assigned", u["vid"], u["rid"])

        await self.writer.submit(op)
        for _, ts in placed:
            for t in ts:
                self.push(t.vehicle_id, {"type": "assignment", "trip": t.message()})

    # ----------------------------------------------------------------------------------------- views
    def waiting_at(self) -> dict[str, int]:
        """Riders (seats) waiting at each stop: queued or assigned, not yet picked up."""
        out: dict[str, int] = dict.fromkeys(self.route.order, 0)
        for ride in self.rides.values():
            if ride["state"] in ("waiting", "assigned"):
                out[ride["origin"]] = out.get(ride["origin"], 0) + ride["seats"]
        return out

    def snapshot(self) -> dict[str, Any]:
        # Rides are kept in creation order, so the newest are at the end.
        recent = list(itertools.islice(reversed(self.rides.values()), 200))
        return {
            "type": "snapshot",
            "time_us": now_us(),
            "vehicles": [vehicle_view(v) for v in self.vehicles.values()],
            "stops": [{"id": k, "waiting": n} for k, n in self.waiting_at().items()],
            "rides": [ride_view(r) for r in recent],
            "queued": len(self.waiting),
        }
