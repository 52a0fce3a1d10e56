"""The dispatch server: FastAPI routes for riders, operators and vehicles, the WebSockets, the dashboard.

``create_app`` builds the app around one database URL; ``lastmile serve`` runs it on uvicorn. Static
pages are public (they hold no data); every API call and WebSocket needs a bearer token.
"""

from __future__ import annotations

import asyncio
import datetime
import io
import json
import logging
import zipfile
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from fastapi import (
    Depends,
    FastAPI,
    HTTPException,
    Query,
    Request,
    Response,
    WebSocket,
    status,
)
from fastapi import (
    Path as PathParam,
)
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.staticfiles import StaticFiles
from sqlalchemy import func, select

from lastmile.fleet import api_models as api
from lastmile.fleet import storage as db
from lastmile.fleet.auth import Principal, check_role
from lastmile.fleet.dispatcher import Dispatcher
from lastmile.fleet.live import Hub
from lastmile.fleet.map_view import map_json
from lastmile.fleet.rate_limit import RateLimit, TokenBuckets, charge_token, default_limits
from lastmile.fleet.request_guard import RequestGuard, validation_error_without_input
from lastmile.fleet.scheduling import LoopRoute, Planner, SchedulingConfig
from lastmile.fleet.service_views import ride_view, vehicle_view
from lastmile.hdmap.service_route import ServiceRoute, campus_service

log = logging.getLogger(__name__)
STATIC = Path(__file__).with_name("static")
bearer = HTTPBearer(auto_error=False, description="Token with a role: rider, operator or vehicle.")


@dataclass(frozen=True, slots=True, kw_only=True)
class ServerConfig:
    """Where the server keeps things.

    Attributes:
        db_url: SQLAlchemy URL (``sqlite:///...`` or ``postgresql://...``).
        out_dir: directory for ``tokens.json`` (tokens made at first start) and the default SQLite file.
        runs_dir: recorded runs operators may browse and download.
        commit_batch: most writes one commit may carry; 1 is the naive commit-per-request design
            (kept as the load benchmark's baseline).
        timetable_lead_s: timetable runs are handed to a shuttle this long before they depart, by
            the server's local clock (0 turns the timetable clock off: operators assign runs).
        max_body_bytes: largest request body accepted (413 beyond; the largest legitimate body of
            the API is under 1 kB).
        body_timeout_s: time a request body has to arrive in full (408 beyond).
        rate_limits: requests per token, by the token's role (429 with Retry-After beyond).
        route: the service the fleet runs (a route file's, loaded by the caller so that a bad one is an
            error before the server starts); None: the campus loop.
    """

    db_url: str
    out_dir: Path
    runs_dir: Path
    scheduling: SchedulingConfig = field(default_factory=SchedulingConfig)
    commit_batch: int = 512
    timetable_lead_s: float = 600.0
    max_body_bytes: int = 65_536
    body_timeout_s: float = 10.0
    rate_limits: dict[str, RateLimit] = field(default_factory=default_limits)
    route: ServiceRoute | None = None


def _principal(request: Request, creds: HTTPAuthorizationCredentials | None) -> Principal:
    book = request.app.state.dispatcher.tokens
    header = request.headers.get("authorization")
    if creds is None:
        return book.authenticate(header)
    return book.authenticate_token(creds.credentials)


def role(*roles: str) -> Any:
    # async: FastAPI would run a plain function in its thread pool, a thread hop on every request.
    async def dep(
        request: Request, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]
    ) -> Principal:
        principal = _principal(request, creds)
        check_role(principal, roles)
        return principal

    return Depends(dep)


Anyone = Annotated[Principal, role("rider", "operator", "vehicle")]
Rider = Annotated[Principal, role("rider", "operator")]
Operator = Annotated[Principal, role("operator")]
OperatorOrVehicle = Annotated[Principal, role("operator", "vehicle")]
Infrastructure = Annotated[Principal, role("infrastructure", "operator")]
# Ride ids are 26 hex characters; the bound keeps a 404's message from echoing a long path back.
RideIdParam = Annotated[str, PathParam(min_length=1, max_length=64)]
VehicleIdParam = Annotated[str, PathParam(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")]


async def _timetable_clock(dispatcher: Dispatcher, config: ServerConfig) -> None:
    """Every 15 s, hand out the timetable runs about to depart (local time of day)."""
    while True:
        now = datetime.datetime.now()
        midnight = now.replace(hour=0, minute=0, second=0, microsecond=0)
        try:
            await dispatcher.auto_dispatch_timetable(
                (now - midnight).total_seconds(), now.date().isoformat(), config.timetable_lead_s
            )
        except Exception:  # a failed write is retried on the next tick; the clock must keep going
            log.exception("timetable clock")
        await asyncio.sleep(15.0)


def create_app(config: ServerConfig) -> FastAPI:
    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        engine = db.make_engine(config.db_url)
        writer = db.Writer(engine, max_batch=config.commit_batch)
        service = config.route if config.route is not None else campus_service()
        route = LoopRoute(service)
        dispatcher = Dispatcher(engine, writer, route, Planner(route, config.scheduling))
        created = dispatcher.load()
        if created:
            config.out_dir.mkdir(parents=True, exist_ok=True)
            path = config.out_dir / "tokens.json"
            path.write_text(json.dumps(created, indent=2) + "\n")
            path.chmod(0o600)
            log.warning("first start: tokens written to %s", path)
        writer.start(asyncio.get_running_loop())
        hub = Hub(dispatcher)
        dispatcher.push = hub.push_vehicle
        app.state.dispatcher = dispatcher
        app.state.hub = hub
        app.state.map = map_json(service.hdmap, route)
        hub.start()
        clock = (
            asyncio.create_task(_timetable_clock(dispatcher, config)) if config.timetable_lead_s > 0 else None
        )
        try:
            yield
        finally:
            if clock is not None:
                clock.cancel()
            await hub.stop()
            await asyncio.get_running_loop().run_in_executor(None, writer.stop)
            engine.dispose()

    app = FastAPI(
        title="lastmile dispatch",
        version="0.1.0",
        description="Campus shuttle dispatch: rides, vehicles, timetable, live state.",
        lifespan=lifespan,
    )

    app.state.buckets = TokenBuckets(config.rate_limits)
    app.add_middleware(
        RequestGuard,
        max_body_bytes=config.max_body_bytes,
        body_timeout_s=config.body_timeout_s,
        admit=charge_token,
    )
    app.add_exception_handler(RequestValidationError, validation_error_without_input)

    def disp(request: Request) -> Dispatcher:
        return request.app.state.dispatcher

    # ----------------------------------------------------------------------------- pages (public)
    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(STATIC / "index.html")

    @app.get("/rider", include_in_schema=False)
    def rider_page() -> FileResponse:
        return FileResponse(STATIC / "rider.html")

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon() -> Response:
        return Response(status_code=204)

    # ----------------------------------------------------------------------------- shared
    @app.get("/api/map", tags=["map"])
    async def campus_map(request: Request, _who: Anyone) -> dict[str, Any]:
        """Lanelet outlines, the service loop, stops and buildings (metres, map frame)."""
        return request.app.state.map

    @app.get("/api/stops", tags=["map"], response_model=list[api.StopOut])
    async def list_stops(request: Request, _who: Anyone) -> list[dict[str, Any]]:
        d = disp(request)
        waiting = d.waiting_at()
        return [
            {
                "id": s.id,
                "name": s.name,
                "x_m": s.x_m,
                "y_m": s.y_m,
                "route_s_m": s.route_s_m,
                "waiting": waiting[s.id],
            }
            for s in d.route.stops.values()
        ]

    @app.get("/api/timetable", tags=["map"], response_model=list[api.TimetableOut])
    async def list_timetable(request: Request, _who: Anyone) -> list[dict[str, Any]]:
        out = []
        for e in disp(request).timetable:
            t = round(e["time_s"])
            clock = f"{t // 3600:02d}:{t % 3600 // 60:02d}:{t % 60:02d}"
            out.append({k: e[k] for k in ("run_id", "shift", "seq", "stop_id", "time_s")} | {"clock": clock})
        return out

    @app.get("/api/whoami", tags=["auth"])
    async def whoami(who: Anyone) -> dict[str, str]:
        return {"role": who.role, "subject": who.subject}

    # ----------------------------------------------------------------------------- riders
    @app.post("/api/rides", tags=["rides"], response_model=api.RideOut, status_code=201)
    async def request_ride(
        request: Request, body: api.RideRequestIn, who: Rider, response: Response
    ) -> dict[str, Any]:
        """Ask for a ride between two stops; the answer carries the estimated pick-up time."""
        view, created = await disp(request).create_ride(
            who, body.origin, body.destination, body.seats, body.client_ref
        )
        if not created:
            response.status_code = status.HTTP_200_OK
        return view

    @app.get("/api/rides/{ride_id}", tags=["rides"], response_model=api.RideOut)
    async def get_ride(request: Request, ride_id: RideIdParam, who: Rider) -> dict[str, Any]:
        d = disp(request)
        return ride_view(d.ride_or_404(ride_id, who))

    @app.delete("/api/rides/{ride_id}", tags=["rides"], response_model=api.RideOut)
    async def cancel_ride(request: Request, ride_id: RideIdParam, who: Rider) -> dict[str, Any]:
        return await disp(request).cancel_ride(who, ride_id)

    @app.get("/api/rides/{ride_id}/vehicle", tags=["rides"], response_model=api.VehicleOut)
    async def follow_shuttle(request: Request, ride_id: RideIdParam, who: Rider) -> dict[str, Any]:
        """Where the rider's shuttle is now."""
        d = disp(request)
        ride = d.ride_or_404(ride_id, who)
        if not ride["vehicle_id"]:
            raise HTTPException(
                status.HTTP_409_CONFLICT, f"ride {ride_id!r} has no shuttle yet: {ride['reason']}"
            )
        return vehicle_view(d.vehicle_or_404(ride["vehicle_id"]))

    @app.get("/api/rides", tags=["rides"], response_model=list[api.RideOut])
    async def list_rides(
        request: Request,
        who: Rider,
        state: Annotated[str | None, Query(pattern=r"^(waiting|assigned|picked_up)$")] = None,
        limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    ) -> list[dict[str, Any]]:
        """Active rides (a rider sees only their own)."""
        d = disp(request)
        rides = [
            r
            for r in d.rides.values()
            if (state is None or r["state"] == state) and (who.role != "rider" or r["rider"] == who.subject)
        ]
        return [ride_view(r) for r in rides[-limit:]]

    @app.get("/api/ride-log", tags=["rides"], response_model=api.RidePage)
    def ride_log(
        request: Request,
        _who: Operator,
        state: Annotated[
            str | None, Query(pattern=r"^(waiting|assigned|picked_up|dropped_off|cancelled)$")
        ] = None,
        vehicle_id: Annotated[str | None, Query(max_length=64)] = None,
        stop: Annotated[str | None, Query(max_length=16, description="origin or destination")] = None,
        offset: Annotated[int, Query(ge=0, le=2**62)] = 0,
        limit: Annotated[int, Query(ge=1, le=500)] = 50,
    ) -> dict[str, Any]:
        """Every ride ever requested, newest first, a page at a time; filtered by state, shuttle, stop."""
        t = db.ride_requests
        where = []
        if state is not None:
            where.append(t.c.state == state)
        if vehicle_id is not None:
            where.append(t.c.vehicle_id == vehicle_id)
        if stop is not None:
            where.append((t.c.origin == stop) | (t.c.destination == stop))
        with disp(request).engine.connect() as conn:
            total = conn.execute(select(func.count()).select_from(t).where(*where)).scalar_one()
            rows = conn.execute(
                select(t)
                .where(*where)
                .order_by(t.c.created_us.desc(), t.c.id.desc())
                .offset(offset)
                .limit(limit)
            ).all()
        rides = [ride_view(dict(r._mapping)) for r in rows]
        return {"total": total, "offset": offset, "limit": limit, "rides": rides}

    # ----------------------------------------------------------------------------- operators
    @app.post("/api/vehicles", tags=["vehicles"], response_model=api.VehicleOut, status_code=201)
    async def register_vehicle(
        request: Request, body: api.VehicleIn, who: OperatorOrVehicle, response: Response
    ) -> dict[str, Any]:
        """Register a shuttle (operators any id; a vehicle token only its own subject, unless '*')."""
        if who.role == "vehicle" and who.subject not in ("*", body.id):
            raise HTTPException(
                status.HTTP_403_FORBIDDEN, f"vehicle token for {who.subject!r} cannot register {body.id!r}"
            )
        view, created = await disp(request).register_vehicle(body.id, body.name, body.capacity)
        if not created:
            response.status_code = status.HTTP_200_OK
        return view

    @app.get("/api/vehicles", tags=["vehicles"], response_model=list[api.VehicleOut])
    async def list_vehicles(request: Request, _who: Operator) -> list[dict[str, Any]]:
        d = disp(request)
        return [vehicle_view(v) for v in d.vehicles.values()]

    @app.get("/api/vehicles/{vehicle_id}", tags=["vehicles"], response_model=api.VehicleOut)
    async def get_vehicle(request: Request, vehicle_id: VehicleIdParam, _who: Operator) -> dict[str, Any]:
        d = disp(request)
        return vehicle_view(d.vehicle_or_404(vehicle_id))

    @app.post("/api/vehicles/{vehicle_id}/command", tags=["vehicles"], response_model=api.VehicleOut)
    async def command_vehicle(
        request: Request, vehicle_id: VehicleIdParam, body: api.CommandIn, who: Operator
    ) -> dict[str, Any]:
        """Start or suspend service, emergency stop, release it. Riders and vehicles get 403."""
        return await disp(request).command(who, vehicle_id, body.command, body.reason)

    @app.post("/api/vehicles/{vehicle_id}/timetable-run", tags=["vehicles"])
    async def assign_run(
        request: Request, vehicle_id: VehicleIdParam, body: api.TimetableRunIn, _who: Operator
    ) -> list[dict[str, Any]]:
        """Hand a timetable run (every stop once around the loop) to a shuttle."""
        return await disp(request).assign_timetable_run(vehicle_id, body.run_id)

    # ----------------------------------------------------------------------------- infrastructure
    @app.post("/api/infrastructure/presence", tags=["infrastructure"])
    async def report_presence(request: Request, body: api.PresenceIn, who: Infrastructure) -> dict[str, int]:
        """A crossing camera's pedestrian presence, relayed at once to every connected vehicle (NUS)."""
        if who.role == "infrastructure" and who.subject not in ("*", body.node_id):
            raise HTTPException(
                status.HTTP_403_FORBIDDEN,
                f"infrastructure token for {who.subject!r} cannot report as {body.node_id!r}",
            )
        n = disp(request).broadcast_presence(body.node_id, body.crosswalk, body.present, body.captured_us)
        return {"delivered_to": n}

    @app.get("/api/infrastructure", tags=["infrastructure"])
    async def list_presence(request: Request, _who: Anyone) -> list[dict[str, Any]]:
        """The newest report of each infrastructure node."""
        return list(disp(request).presence.values())

    @app.post("/api/tokens", tags=["auth"], response_model=api.TokenOut, status_code=201)
    async def issue_token(request: Request, body: api.TokenIn, _who: Operator) -> dict[str, str]:
        tok = await disp(request).issue_token(body.role, body.subject)
        return {"token": tok, "role": body.role, "subject": body.subject}

    @app.get("/api/events", tags=["operations"], response_model=list[api.EventOut])
    def list_events(
        request: Request,
        _who: Operator,
        after: Annotated[int, Query(ge=0, le=2**62)] = 0,
        limit: Annotated[int, Query(ge=1, le=1000)] = 100,
        newest_first: Annotated[bool, Query(description="the newest events (after `after`) first")] = False,
    ) -> list[dict[str, Any]]:
        """Events with an id above ``after``: the oldest first, or the newest first (the dashboard)."""
        order = db.events.c.id.desc() if newest_first else db.events.c.id
        with disp(request).engine.connect() as conn:
            rows = conn.execute(
                select(db.events).where(db.events.c.id > after).order_by(order).limit(limit)
            ).all()
        return [dict(r._mapping) for r in rows]

    @app.get("/api/runs", tags=["runs"], response_model=list[api.RunOut])
    def list_runs(_who: Operator) -> list[dict[str, Any]]:
        """Recorded runs (directories under the runs directory)."""
        root = config.runs_dir
        out = []
        if root.is_dir():
            for d in sorted(p for p in root.iterdir() if p.is_dir()):
                files = sorted(str(f.relative_to(d)) for f in d.rglob("*") if f.is_file())
                out.append(
                    {"name": d.name, "files": files, "bytes": sum((d / f).stat().st_size for f in files)}
                )
        return out

    def run_path(name: str, rel: str = "") -> Path:
        root = config.runs_dir.resolve()
        path = (root / name / rel).resolve()
        if not path.is_relative_to(root / name) or not (root / name).is_dir() or not path.exists():
            raise HTTPException(
                status.HTTP_404_NOT_FOUND, f"no run file {name[:80]!r}/{rel[:200]!r} under the runs directory"
            )
        return path

    @app.get("/api/runs/{name}/files/{rel:path}", tags=["runs"])
    def download_run_file(name: str, rel: str, _who: Operator) -> FileResponse:
        path = run_path(name, rel)
        if not path.is_file():
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"{name[:80]!r}/{rel[:200]!r} is not a file")
        return FileResponse(path, filename=path.name)

    @app.get("/api/runs/{name}/archive", tags=["runs"])
    def download_run(name: str, _who: Operator) -> Response:
        """The whole run directory as a zip file."""
        base = run_path(name)
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
            for f in sorted(base.rglob("*")):
                if f.is_file():
                    zf.write(f, str(Path(name) / f.relative_to(base)))
        return Response(
            buf.getvalue(),
            media_type="application/zip",
            headers={"Content-Disposition": f'attachment; filename="{name}.zip"'},
        )

    # ----------------------------------------------------------------------------- WebSockets
    async def ws_principal(ws: WebSocket, roles: tuple[str, ...]) -> Principal | None:
        book = ws.app.state.dispatcher.tokens
        header = ws.headers.get("authorization")
        token = ws.query_params.get("token")
        try:
            principal = book.authenticate_token(token) if token and not header else book.authenticate(header)
            check_role(principal, roles)
        except HTTPException as exc:
            await ws.accept()
            await ws.close(code=4000 + exc.status_code, reason=str(exc.detail)[:120])
            return None
        return principal

    @app.websocket("/ws/live")
    async def live(ws: WebSocket) -> None:
        """Snapshots of the whole service (vehicles, waiting riders, rides) whenever something changes."""
        who = await ws_principal(ws, ("rider", "operator", "vehicle"))
        if who is None:
            return
        await ws.accept()
        await ws.app.state.hub.serve_live(ws)

    @app.websocket("/ws/vehicle/{vehicle_id}")
    async def vehicle_socket(ws: WebSocket, vehicle_id: str) -> None:
        """A vehicle's link: status in; assignments, cancellations and commands out; resumable."""
        who = await ws_principal(ws, ("vehicle",))
        if who is None:
            return
        d: Dispatcher = ws.app.state.dispatcher
        if who.subject not in ("*", vehicle_id) or vehicle_id not in d.vehicles:
            await ws.accept()
            reason = (
                "unknown vehicle: register it first"
                if vehicle_id not in d.vehicles
                else "token for another vehicle"
            )
            await ws.close(
                code=4403 if vehicle_id in d.vehicles else 4404, reason=f"{vehicle_id!r}: {reason}"
            )
            return
        await ws.accept()
        await ws.app.state.hub.serve_vehicle(ws, vehicle_id)

    return app
