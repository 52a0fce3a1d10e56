"""Start-up: create the tables, seed what is empty, and read back everything the dispatcher holds.

The database is the dispatcher's only memory across restarts: everything it keeps in memory is rebuilt
from here, so a restart loses nothing that was acknowledged.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import Connection, Engine, func, insert, select

from lastmile.fleet import storage as db
from lastmile.fleet.auth import new_token, token_hash
from lastmile.fleet.scheduling import LoopRoute, Planner, Visit, build_timetable
from lastmile.fleet.service_records import ACTIVE_RIDE_STATES, TripState, VehicleState, now_us

log = logging.getLogger(__name__)


@dataclass(slots=True, kw_only=True)
class LoadedService:
    """What the database holds, as the dispatcher keeps it in memory.

    Attributes:
        created_tokens: role -> token, for the tokens seeded now (an empty table); shown once.
        tokens: (sha256, role, subject) of every token not revoked.
        timetable: the timetable rows, by run and call order.
        vehicles: every registered shuttle, with the plan of its open trips.
        rides: the active rides (waiting, assigned or picked up), oldest first.
        by_ref: (rider, client reference) -> ride id, of every ride ever made (idempotent re-requests).
        trips: the open trips (pending or acknowledged), by id.
        next_trip: the id the next trip gets.
        runs_dispatched: (service date, run id) the timetable clock has handed out.
    """

    created_tokens: dict[str, str] = field(default_factory=dict)
    tokens: list[tuple[str, str, str]] = field(default_factory=list)
    timetable: list[dict[str, Any]] = field(default_factory=list)
    vehicles: dict[str, VehicleState] = field(default_factory=dict)
    rides: list[dict[str, Any]] = field(default_factory=list)
    by_ref: dict[tuple[str, str], str] = field(default_factory=dict)
    trips: dict[int, TripState] = field(default_factory=dict)
    next_trip: int = 1
    runs_dispatched: set[tuple[str, str]] = field(default_factory=set)


def _seed(conn: Connection, route: LoopRoute, planner: Planner) -> dict[str, str]:
    """Fill the stops, timetable and tokens tables where they are empty; returns the tokens created."""
    created: dict[str, str] = {}
    if conn.execute(select(func.count()).select_from(db.stops)).scalar_one() == 0:
        conn.execute(
            insert(db.stops),
            [
                {"id": s.id, "name": s.name, "x_m": s.x_m, "y_m": s.y_m, "route_s_m": s.route_s_m}
                for s in route.stops.values()
            ],
        )
    if conn.execute(select(func.count()).select_from(db.timetable)).scalar_one() == 0:
        conn.execute(
            insert(db.timetable),
            [
                {"run_id": e.run_id, "shift": e.shift, "seq": e.seq, "stop_id": e.stop_id, "time_s": e.time_s}
                for e in build_timetable(route, planner.config)
            ],
        )
    if conn.execute(select(func.count()).select_from(db.tokens)).scalar_one() == 0:
        for role, subject in (("operator", "operator"), ("rider", "rider"), ("vehicle", "*")):
            tok = new_token(role)
            conn.execute(
                insert(db.tokens).values(
                    sha256=token_hash(tok), role=role, subject=subject, created_us=now_us(), revoked=False
                )
            )
            created[role] = tok
    return created


def load_service(engine: Engine, route: LoopRoute, planner: Planner) -> LoadedService:
    """Create (or upgrade) the tables, seed what is empty, and read the service back (one transaction)."""
    with engine.begin() as conn:
        db.scope_idempotency_keys(conn)
    db.metadata.create_all(engine)
    out = LoadedService()
    with engine.begin() as conn:
        out.created_tokens = _seed(conn, route, planner)
        stop_ids = {r.id for r in conn.execute(select(db.stops.c.id))}
        missing = set(route.order) - stop_ids
        if missing:
            log.warning("stops table lacks map stops %s", sorted(missing))
        out.tokens = [
            (r.sha256, r.role, r.subject)
            for r in conn.execute(select(db.tokens).where(db.tokens.c.revoked.is_(False)))
        ]
        out.timetable = [
            dict(r._mapping)
            for r in conn.execute(select(db.timetable).order_by(db.timetable.c.run_id, db.timetable.c.seq))
        ]
        for r in conn.execute(select(db.vehicles)):
            m = dict(r._mapping)
            out.vehicles[m["id"]] = VehicleState(**m)
        out.rides = [
            dict(r._mapping)
            for r in conn.execute(
                select(db.ride_requests)
                .where(db.ride_requests.c.state.in_(ACTIVE_RIDE_STATES))
                .order_by(db.ride_requests.c.created_us)
            )
        ]
        t = db.ride_requests
        for r in conn.execute(select(t.c.id, t.c.rider, t.c.client_ref).where(t.c.client_ref.is_not(None))):
            out.by_ref[(r.rider, r.client_ref)] = r.id
        out.next_trip = (conn.execute(select(func.max(db.trips.c.id))).scalar_one() or 0) + 1
        for r in conn.execute(select(db.events.c.detail).where(db.events.c.kind == "timetable_run_assigned")):
            if r.detail and r.detail.get("date"):
                out.runs_dispatched.add((r.detail["date"], r.detail["run_id"]))
        rows = conn.execute(
            select(db.trips)
            .where(db.trips.c.state.in_(("pending", "acked")))
            .order_by(db.trips.c.vehicle_id, db.trips.c.visit, db.trips.c.id)
        ).all()
    # Plans are rebuilt from the open trips in visit order: one visit per run of equal visit numbers.
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
        out.trips[trip.id] = trip
        vehicle = out.vehicles.get(r.vehicle_id)
        if vehicle is None:
            continue
        if last != (r.vehicle_id, r.visit):
            vehicle.plan.append(Visit(stop_id=r.stop_id))
            last = (r.vehicle_id, r.visit)
        vehicle.plan[-1].items.append(trip.plan_item())
    return out
