"""The dispatcher: the live state of the service, its rules, and the writes that make it durable.

It runs on the server's event loop, so its state needs no locks. Every change is applied in memory,
queued to the group-committing writer, and only acknowledged (to the HTTP caller, or pushed to a
vehicle) after the commit: what anyone has been told is in the database. On start it rebuilds all of
its state from the database, which is what makes a restart lose nothing.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fastapi import HTTPException, status
from sqlalchemy import Connection, Engine, bindparam, func, insert, select, update

from lastmile.fleet import scheduling
from lastmile.fleet import storage as db
from lastmile.fleet.auth import Principal, TokenBook, new_token, token_hash
from lastmile.fleet.scheduling import (
    CAPACITY_SEATS,
    LoopRoute,
    PlanItem,
    Planner,
    Visit,
    build_timetable,
)

log = logging.getLogger(__name__)
ACTIVE_RIDE_STATES = ("waiting", "assigned", "picked_up")
INSERT_RIDE = insert(db.ride_requests)
INSERT_EVENT = insert(db.events)
DRAIN_BATCH = 50  # queued rides retried per change of a plan; bounds the work one event can cause


def now_us() -> int:
    return time.time_ns() // 1000


@dataclass(slots=True, kw_only=True)
class VehicleState:
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
    id: int
    vehicle_id: str
    kind: str
    stop_id: str
    request_id: str | None
    run_id: str | None
    seats: int
    state: str

    def message(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "kind": self.kind,
            "stop_id": self.stop_id,
            "request_id": self.request_id,
            "run_id": self.run_id,
            "seats": self.seats,
        }


class Dispatcher:
    """Service state and rules. ``push`` sends a JSON message to a connected vehicle (set by the server)."""

    def __init__(self, engine: Engine, writer: db.Writer, route: LoopRoute, planner: Planner) -> None:
        self.engine = engine
        self.writer = writer
        self.route = route
        self.planner = planner
        self.tokens = TokenBook()
        self.vehicles: dict[str, VehicleState] = {}
        self.rides: dict[str, dict[str, Any]] = {}
        self.by_ref: dict[str, str] = {}
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
        db.metadata.create_all(self.engine)
        created: dict[str, str] = {}
        with self.engine.begin() as conn:
            if conn.execute(select(func.count()).select_from(db.stops)).scalar_one() == 0:
                conn.execute(
                    insert(db.stops),
                    [
                        {"id": s.id, "name": s.name, "x_m": s.x_m, "y_m": s.y_m, "route_s_m": s.route_s_m}
                        for s in self.route.stops.values()
                    ],
                )
            if conn.execute(select(func.count()).select_from(db.timetable)).scalar_one() == 0:
                conn.execute(
                    insert(db.timetable),
                    [
                        {
                            "run_id": e.run_id,
                            "shift": e.shift,
                            "seq": e.seq,
                            "stop_id": e.stop_id,
                            "time_s": e.time_s,
                        }
                        for e in build_timetable(self.route, self.planner.config)
                    ],
                )
            if conn.execute(select(func.count()).select_from(db.tokens)).scalar_one() == 0:
                for role, subject in (("operator", "operator"), ("rider", "rider"), ("vehicle", "*")):
                    tok = new_token(role)
                    conn.execute(
                        insert(db.tokens).values(
                            sha256=token_hash(tok),
                            role=role,
                            subject=subject,
                            created_us=now_us(),
                            revoked=False,
                        )
                    )
                    created[role] = tok
            stop_ids = {r.id for r in conn.execute(select(db.stops.c.id))}
            missing = set(self.route.order) - stop_ids
            if missing:
                log.warning("stops table lacks map stops %s", sorted(missing))
            for r in conn.execute(select(db.tokens).where(db.tokens.c.revoked.is_(False))):
                self.tokens.add(r.sha256, r.role, r.subject)
            self.timetable = [
                dict(r._mapping)
                for r in conn.execute(
                    select(db.timetable).order_by(db.timetable.c.run_id, db.timetable.c.seq)
                )
            ]
            for r in conn.execute(select(db.vehicles)):
                m = dict(r._mapping)
                self.vehicles[m["id"]] = VehicleState(**m)
            for r in conn.execute(
                select(db.ride_requests)
                .where(db.ride_requests.c.state.in_(ACTIVE_RIDE_STATES))
                .order_by(db.ride_requests.c.created_us)
            ):
                ride = dict(r._mapping)
                self._remember(ride)
            for r in conn.execute(select(db.ride_requests.c.id, db.ride_requests.c.client_ref)):
                if r.client_ref:
                    self.by_ref[r.client_ref] = r.id
            self._next_trip = (conn.execute(select(func.max(db.trips.c.id))).scalar_one() or 0) + 1
            for r in conn.execute(
                select(db.events.c.detail).where(db.events.c.kind == "timetable_run_assigned")
            ):
                if r.detail and r.detail.get("date"):
                    self.runs_dispatched.add((r.detail["date"], r.detail["run_id"]))
            rows = conn.execute(
                select(db.trips)
                .where(db.trips.c.state.in_(("pending", "acked")))
                .order_by(db.trips.c.vehicle_id, db.trips.c.visit, db.trips.c.id)
            ).all()
        last: tuple[str, int] | None = None
        for r in rows:
            trip = TripState(
                id=r.id,
                vehicle_id=r.vehicle_id,
                kind=r.kind,
                stop_id=r.stop_id,
                request_id=r.request_id,
                run_id=r.run_id,
                seats=r.seats,
                state=r.state,
            )
            self.trips[trip.id] = trip
            vehicle = self.vehicles.get(r.vehicle_id)
            if vehicle is None:
                continue
            if last != (r.vehicle_id, r.visit):
                vehicle.plan.append(Visit(stop_id=r.stop_id))
                last = (r.vehicle_id, r.visit)
            vehicle.plan[-1].items.append(self._item(trip))
        return created

    def _remember(self, ride: dict[str, Any]) -> None:
        self.rides[ride["id"]] = ride
        if ride["state"] == "waiting":
            self.waiting[ride["id"]] = None
        else:
            self.waiting.pop(ride["id"], None)

    @staticmethod
    def _item(trip: TripState) -> PlanItem:
        return PlanItem(
            trip_id=trip.id, kind=trip.kind, request_id=trip.request_id, seats=trip.seats, run_id=trip.run_id
        )

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

    def ride_view(self, ride: dict[str, Any]) -> dict[str, Any]:
        eta_s = None
        if ride["state"] == "assigned" and ride["eta_pickup_us"] is not None:
            eta_s = max(0.0, (ride["eta_pickup_us"] - now_us()) / 1e6)
        return {
            k: ride[k]
            for k in (
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
        } | {"eta_pickup_s": eta_s}

    def vehicle_view(self, v: VehicleState) -> dict[str, Any]:
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
                self.push(v.id, self.plan_message(v))

    @staticmethod
    def plan_message(v: VehicleState) -> dict[str, Any]:
        """The order in which the vehicle should serve its trips: one entry per stop visit."""
        return {
            "type": "plan",
            "visits": [
                {"stop_id": visit.stop_id, "trip_ids": [i.trip_id for i in visit.items]} for visit in v.plan
            ],
        }

    def _ride_id(self) -> str:
        """A random per-process prefix and a counter: unique across restarts without a system call per
        ride (``uuid4`` reads the OS's entropy each time, 75-400 us on this shared machine)."""
        self._id_counter += 1
        return f"{self._id_prefix}{self._id_counter:010x}"

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
        if client_ref is not None and client_ref in self.by_ref:
            return self.ride_view(self.ride_or_404(self.by_ref[client_ref], principal)), False
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
        if client_ref is not None:
            self.by_ref[client_ref] = ride["id"]
        new_trips, vehicle = self._assign(ride)
        if vehicle is None and not any(v.service == "in_service" for v in self.vehicles.values()):
            ride["reason"] = "queued: no shuttle is in service"
        row = {k: ride[k] for k in ride}
        rows = self._visit_rows(vehicle) if vehicle else []
        trip_rows = [self._trip_row(t) for t in new_trips]

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
        return self.ride_view(ride), True

    def _forget_failed(self, ride: dict[str, Any], new_trips: list[TripState]) -> None:
        self.rides.pop(ride["id"], None)
        self.waiting.pop(ride["id"], None)
        if ride.get("client_ref"):
            self.by_ref.pop(ride["client_ref"], None)
        for t in new_trips:
            self._drop_from_plan(t)

    def _trip_row(self, t: TripState) -> dict[str, Any]:
        return {
            "id": t.id,
            "vehicle_id": t.vehicle_id,
            "kind": t.kind,
            "stop_id": t.stop_id,
            "request_id": t.request_id,
            "run_id": t.run_id,
            "seats": t.seats,
            "visit": 0,
            "state": t.state,
            "created_us": now_us(),
            "done_us": None,
        }

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
        plan = self.planner.insert(v.plan, s, best.pickup_at_m, ride["origin"], self._item(pick))
        v.plan = self.planner.insert(plan, s, best.dropoff_at_m, ride["destination"], self._item(drop))
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
        return self.ride_view(snapshot)

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
        trip_rows = [self._trip_row(t) for _, ts in placed for t in ts]
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

    # ----------------------------------------------------------------------------------------- vehicles
    async def register_vehicle(
        self, vehicle_id: str, name: str, capacity: int
    ) -> tuple[dict[str, Any], bool]:
        existing = self.vehicles.get(vehicle_id)
        if existing is not None:
            return self.vehicle_view(existing), False
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
        return self.vehicle_view(v), True

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
        return self.vehicle_view(v)

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
            v.plan = self.planner.insert(v.plan, s, at, call["stop_id"], self._item(trip))
            new.append(trip)
            prev = call["stop_id"]
        rows = [self._trip_row(t) for t in new]
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

    def resume_messages(self, vehicle_id: str) -> list[dict[str, Any]]:
        """What a (re)connecting vehicle must hear: its service state and every trip not yet done."""
        v = self.vehicles[vehicle_id]
        msgs: list[dict[str, Any]] = [{"type": "service", "service": v.service}]
        for visit in v.plan:
            for item in visit.items:
                msgs.append({"type": "assignment", "trip": self.trips[item.trip_id].message()})
        msgs.append(self.plan_message(v))
        self._plan_sent[vehicle_id] = v.plan
        return msgs

    def broadcast_presence(self, node_id: str, crosswalk: int, present: bool, captured_us: int) -> int:
        """Relay an infrastructure node's pedestrian presence to every connected vehicle, as it came;
        returns how many vehicles it was queued to."""
        msg = {
            "type": "infrastructure",
            "node_id": node_id,
            "crosswalk": crosswalk,
            "present": present,
            "captured_us": captured_us,
        }
        self.presence[node_id] = {**msg, "received_us": now_us()}
        sent = 0
        for v in self.vehicles.values():
            if v.connected:
                self.push(v.id, msg)
                sent += 1
        return sent

    def vehicle_status(self, vehicle_id: str, msg: dict[str, Any]) -> None:
        """A status report: memory now, database without waiting (a lost status is replaced by the next)."""
        v = self.vehicles[vehicle_id]
        for key in ("x_m", "y_m", "yaw_rad", "speed_mps", "behaviour", "health", "passengers", "door"):
            if key in msg:
                setattr(v, key, msg[key])
        if msg.get("hmi") is not None:
            v.hmi = dict(msg["hmi"])
        if v.x_m is not None and v.y_m is not None:
            v.route_s_m = self.route.project_s(v.x_m, v.y_m, v.route_s_m)
        v.last_status_us = now_us()
        values = {
            k: getattr(v, k)
            for k in (
                "x_m",
                "y_m",
                "yaw_rad",
                "speed_mps",
                "route_s_m",
                "behaviour",
                "health",
                "passengers",
                "door",
                "last_status_us",
            )
        }
        self.writer.submit_nowait(
            lambda conn: conn.execute(
                update(db.vehicles).where(db.vehicles.c.id == vehicle_id).values(**values)
            )
        )
        self._touch()

    async def trip_ack(self, vehicle_id: str, trip_id: int) -> None:
        trip = self.trips.get(trip_id)
        if trip is None or trip.vehicle_id != vehicle_id or trip.state != "pending":
            return
        trip.state = "acked"
        await self.writer.submit(
            lambda conn: conn.execute(update(db.trips).where(db.trips.c.id == trip_id).values(state="acked"))
        )

    async def trip_done(self, vehicle_id: str, trip_id: int) -> bool:
        """The vehicle did a trip (picked up, dropped off, called at the stop). False if already known."""
        trip = self.trips.get(trip_id)
        if trip is None or trip.vehicle_id != vehicle_id:
            return False
        self._drop_from_plan(trip)
        t = now_us()
        ride = self.rides.get(trip.request_id) if trip.request_id else None
        ride_values: dict[str, Any] = {}
        if ride is not None and trip.kind == "pickup":
            ride_values = {"state": "picked_up", "picked_up_us": t}
        elif ride is not None and trip.kind == "dropoff":
            ride_values = {"state": "dropped_off", "dropped_off_us": t, "closed_us": t}
        if ride is not None and ride_values:
            ride.update(ride_values)
            if ride["state"] == "dropped_off":
                self.rides.pop(ride["id"], None)
        v = self.vehicles[vehicle_id]
        renumber = self._visit_rows(v)
        kind_event = {"pickup": "picked_up", "dropoff": "dropped_off"}.get(trip.kind, f"{trip.kind}_served")

        def op(conn: Connection) -> None:
            conn.execute(update(db.trips).where(db.trips.c.id == trip_id).values(state="done", done_us=t))
            if ride_values and trip.request_id:
                conn.execute(
                    update(db.ride_requests)
                    .where(db.ride_requests.c.id == trip.request_id)
                    .values(**ride_values)
                )
            self._renumber(conn, renumber)
            self._event(conn, kind_event, vehicle_id, trip.request_id, trip_id=trip_id, stop_id=trip.stop_id)

        await self.writer.submit(op)
        await self._drain()
        self._touch()
        return True

    async def seat_button(self, vehicle_id: str, seat: int) -> dict[str, Any]:
        """A passenger asks to get off: a seat_stop at the next stop the shuttle can still stop at."""
        v = self.vehicles[vehicle_id]
        s = self._vehicle_s(v)
        stop_id, ahead_m = self.planner.seat_button_stop(s, v.speed_mps or 0.0)
        at = self.planner.first_ahead_m(s, stop_id)
        if at < ahead_m - 1.0:  # the stop is "at" the vehicle but it cannot stop there any more
            at += self.route.length_m
        existing = next(
            (
                i
                for visit, d in zip(v.plan, self.planner.unrolled_m(v.plan, s), strict=True)
                if abs(d - at) < 1e-6
                for i in visit.items
                if i.kind == "seat_stop"
            ),
            None,
        )
        if existing is not None:
            return self.trips[existing.trip_id].message()
        trip = self._new_trip(v.id, "seat_stop", stop_id, seats=0)
        v.plan = self.planner.insert(v.plan, s, at, stop_id, self._item(trip))
        row = self._trip_row(trip)
        renumber = self._visit_rows(v)

        def op(conn: Connection) -> None:
            conn.execute(insert(db.trips).values(**row))
            self._renumber(conn, renumber)
            self._event(conn, "seat_button", vehicle_id, None, seat=seat, stop_id=stop_id)

        await self.writer.submit(op)
        self.push(vehicle_id, {"type": "assignment", "trip": trip.message()})
        self._touch()
        return trip.message()

    def set_connected(self, vehicle_id: str, connected: bool) -> None:
        self.vehicles[vehicle_id].connected = connected
        self._touch()

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
            "vehicles": [self.vehicle_view(v) for v in self.vehicles.values()],
            "stops": [{"id": k, "waiting": n} for k, n in self.waiting_at().items()],
            "rides": [self.ride_view(r) for r in recent],
            "queued": len(self.waiting),
        }
