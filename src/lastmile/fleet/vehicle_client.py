"""A vehicle's link to the dispatch server over its real WebSocket: register, stream status, receive
assignments and commands, and resume after a dropped connection.

The simulator (or a real shuttle's computer) drives one ``VehicleClient`` per vehicle. On every
(re)connection the server sends the vehicle's service state and every trip it has not finished; the
client keeps the trips it knows by id, so a resumed link never hands the same trip to the vehicle
twice. "Done" reports are kept until the server confirms them and sent again after a reconnection;
the server treats a repeated "done" as already known, so nothing is counted twice either.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import websockets
from websockets.asyncio.client import ClientConnection, connect

from lastmile.core.errors import ConfigError

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, kw_only=True)
class Assignment:
    """A trip handed to the vehicle: ``kind`` is pickup, dropoff, timetable or seat_stop."""

    id: int
    kind: str
    stop_id: str
    request_id: str | None
    run_id: str | None
    seats: int


@dataclass(slots=True)
class ClientStats:
    connections: int = 0
    assignments_received: int = 0
    duplicates_ignored: int = 0
    cancels: int = 0
    commands: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)


class VehicleClient:
    """One vehicle's connection. Call ``await start()``; it reconnects by itself until ``stop()``.

    Args:
        base_url: the server, ``http://host:port``.
        vehicle_id: the registered vehicle id (``register()`` registers it over HTTP first).
        token: a bearer token with role ``vehicle`` for this id (or ``*``).
        on_assignment / on_cancel / on_command / on_plan: called on the event loop for each new trip,
            each cancelled trip id, each command (with the new service state), and each new plan.
            The plan (``self.plan``) is the order to serve trips in: (stop id, trip ids) per stop
            visit along the loop; a driver goes to the first visit's stop and reports its trips done.
        on_infrastructure: called with each infrastructure report the server relays (a crossing
            camera's ``{node_id, crosswalk, present, captured_us}``); the newest per node is kept in
            ``self.infrastructure``.
        reconnect_delay_s: wait between reconnection attempts.
    """

    def __init__(
        self,
        base_url: str,
        vehicle_id: str,
        token: str,
        *,
        on_assignment: Callable[[Assignment], None] | None = None,
        on_cancel: Callable[[int], None] | None = None,
        on_command: Callable[[str, str], None] | None = None,
        on_plan: Callable[[list[tuple[str, list[int]]]], None] | None = None,
        on_infrastructure: Callable[[dict[str, Any]], None] | None = None,
        reconnect_delay_s: float = 0.2,
    ) -> None:
        if not base_url.startswith(("http://", "https://")):
            raise ConfigError(f"VehicleClient base_url: expected http://host:port, got {base_url!r}")
        self.base_url = base_url.rstrip("/")
        self.vehicle_id = vehicle_id
        self.token = token
        self.on_assignment = on_assignment
        self.on_cancel = on_cancel
        self.on_command = on_command
        self.on_plan = on_plan
        self.on_infrastructure = on_infrastructure
        # Newest infrastructure report per node: {node_id, crosswalk, present, captured_us}.
        self.infrastructure: dict[str, dict[str, Any]] = {}
        self.plan: list[tuple[str, list[int]]] = []
        self.reconnect_delay_s = reconnect_delay_s
        self.assignments: dict[int, Assignment] = {}
        self.finished: set[int] = set()
        self.service = "unknown"
        self.stats = ClientStats()
        self._unconfirmed: dict[int, asyncio.Future[bool]] = {}
        self._seat_waiters: list[asyncio.Future[dict[str, Any]]] = []
        self._pong_waiters: list[asyncio.Future[None]] = []
        self._ws: ClientConnection | None = None
        self._task: asyncio.Task[None] | None = None
        self._resumed = asyncio.Event()
        self._changed = asyncio.Event()
        self._handlers = self._message_handlers()  # built once, not per message
        self._stopping = False
        self.refused: str | None = None

    @property
    def ws_url(self) -> str:
        return "ws" + self.base_url[len("http") :] + f"/ws/vehicle/{self.vehicle_id}"

    @property
    def connected(self) -> bool:
        return self._ws is not None and self._resumed.is_set()

    async def register(self, name: str = "", capacity: int = 6) -> dict[str, Any]:
        """Register this vehicle over HTTP (idempotent: an existing vehicle is returned as it is)."""
        import httpx

        async with httpx.AsyncClient(base_url=self.base_url, timeout=10) as http:
            res = await http.post(
                "/api/vehicles",
                json={"id": self.vehicle_id, "name": name or self.vehicle_id, "capacity": capacity},
                headers={"Authorization": f"Bearer {self.token}"},
            )
        if res.status_code not in (200, 201):
            raise ConfigError(
                f"register {self.vehicle_id!r}: expected 200/201, got {res.status_code} {res.text}"
            )
        return dict(res.json())

    async def start(self) -> None:
        """Connect and keep connected; returns once the first connection has resumed."""
        self._stopping = False
        self._task = asyncio.create_task(self._run())
        await self.wait_resumed()

    async def wait_resumed(self, timeout_s: float = 10.0) -> None:
        """Wait for the server's "resumed"; raises ConfigError if the server refused the link."""

        async def loop() -> None:
            while not self._resumed.is_set():
                if self.refused is not None:
                    raise ConfigError(f"vehicle {self.vehicle_id!r}: {self.refused}")
                self._changed.clear()
                await self._changed.wait()

        await asyncio.wait_for(loop(), timeout_s)

    async def stop(self) -> None:
        self._stopping = True
        if self._ws is not None:
            await self._ws.close()
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    def drop_connection(self) -> None:
        """Cut the TCP connection without a closing handshake, as a lost radio link would."""
        if self._ws is not None:
            self._resumed.clear()
            self._ws.transport.abort()

    async def _run(self) -> None:
        while not self._stopping:
            try:
                async with connect(
                    self.ws_url, additional_headers={"Authorization": f"Bearer {self.token}"}, open_timeout=10
                ) as ws:
                    self._ws = ws
                    self.stats.connections += 1
                    for trip_id in list(self._unconfirmed):  # reports the server may not have stored
                        await ws.send(json.dumps({"type": "done", "trip_id": trip_id}))
                    async for raw in ws:
                        await self._handle(json.loads(raw))
                    self._check_refused(ws.close_code, ws.close_reason)
            except websockets.ConnectionClosed as exc:
                log.info("vehicle %s link lost: %s", self.vehicle_id, exc)
                if exc.rcvd is not None:
                    self._check_refused(exc.rcvd.code, exc.rcvd.reason)
            except (OSError, websockets.InvalidHandshake, TimeoutError) as exc:
                log.info("vehicle %s link lost: %s", self.vehicle_id, exc)
            finally:
                self._ws = None
                self._resumed.clear()
            if not self._stopping:
                await asyncio.sleep(self.reconnect_delay_s)

    def _check_refused(self, code: int | None, reason: str | None) -> None:
        """A 44xx close (bad token, wrong vehicle, unknown vehicle) will not heal by retrying: give up."""
        if code is not None and 4400 <= code < 4500 and code != 4409:
            self.refused = f"server refused the link: {code} {reason}"
            self.stats.errors.append(self.refused)
            self._stopping = True
            self._changed.set()

    async def _handle(self, msg: dict[str, Any]) -> None:
        kind = msg.get("type")
        if kind == "assignment":
            await self._on_assignment(msg["trip"])  # the one message answered on the link (ack)
        else:
            handler = self._handlers.get(str(kind))
            if handler is not None:
                handler(msg)
        self._changed.set()

    def _message_handlers(self) -> dict[str, Callable[[dict[str, Any]], None]]:
        return {
            "cancel": self._on_cancel,
            "command": self._on_service,
            "service": self._on_service,
            "plan": self._on_plan,
            "done_ack": self._on_done_ack,
            "seat_ack": self._on_seat_ack,
            "infrastructure": self._on_infrastructure,
            "pong": self._on_pong,
            "resumed": lambda _msg: self._resumed.set(),
            "error": lambda msg: self.stats.errors.append(str(msg.get("reason"))),
        }

    async def _on_assignment(self, trip: dict[str, Any]) -> None:
        tid = int(trip["id"])
        if tid in self.assignments or tid in self.finished:
            self.stats.duplicates_ignored += 1
        else:
            a = Assignment(
                id=tid,
                kind=trip["kind"],
                stop_id=trip["stop_id"],
                request_id=trip.get("request_id"),
                run_id=trip.get("run_id"),
                seats=int(trip.get("seats", 0)),
            )
            self.assignments[tid] = a
            self.stats.assignments_received += 1
            if self.on_assignment is not None:
                self.on_assignment(a)
        if self._ws is not None:
            await self._ws.send(json.dumps({"type": "ack", "trip_id": tid}))

    def _on_cancel(self, msg: dict[str, Any]) -> None:
        tid = int(msg["trip_id"])
        if self.assignments.pop(tid, None) is not None:
            self.stats.cancels += 1
            if self.on_cancel is not None:
                self.on_cancel(tid)

    def _on_service(self, msg: dict[str, Any]) -> None:
        self.service = msg["service"]
        if msg.get("type") == "command":
            self.stats.commands.append(msg["command"])
        if self.on_command is not None:
            self.on_command(msg.get("command", "resume"), self.service)

    def _on_plan(self, msg: dict[str, Any]) -> None:
        self.plan = [(v["stop_id"], [int(t) for t in v["trip_ids"]]) for v in msg["visits"]]
        if self.on_plan is not None:
            self.on_plan(self.plan)

    def _on_done_ack(self, msg: dict[str, Any]) -> None:
        fut = self._unconfirmed.pop(int(msg["trip_id"]), None)
        if fut is not None and not fut.done():
            fut.set_result(not msg.get("duplicate", False))

    def _on_seat_ack(self, msg: dict[str, Any]) -> None:
        if self._seat_waiters:
            self._seat_waiters.pop(0).set_result(msg)

    def _on_infrastructure(self, msg: dict[str, Any]) -> None:
        self.infrastructure[str(msg["node_id"])] = msg
        if self.on_infrastructure is not None:
            self.on_infrastructure(msg)

    def _on_pong(self, msg: dict[str, Any]) -> None:
        if self._pong_waiters:
            self._pong_waiters.pop(0).set_result(None)

    async def send_status(
        self,
        *,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        speed_mps: float,
        behaviour: str,
        health: str = "ok",
        passengers: int = 0,
        door: str = "closed",
        hmi: dict[str, str] | None = None,
    ) -> bool:
        """Stream one status report; False (dropped) while disconnected: the next one replaces it."""
        if not self.connected or self._ws is None:
            return False
        msg = {
            "type": "status",
            "x_m": x_m,
            "y_m": y_m,
            "yaw_rad": yaw_rad,
            "speed_mps": speed_mps,
            "behaviour": behaviour,
            "health": health,
            "passengers": passengers,
            "door": door,
        }
        if hmi is not None:  # {cue, light, front, rear, inside, sound}: what the HMI shows now
            msg["hmi"] = hmi
        try:
            await self._ws.send(json.dumps(msg))
        except websockets.ConnectionClosed:
            return False
        return True

    async def complete(self, trip_id: int, timeout_s: float = 10.0) -> bool:
        """Report a trip done and wait until the server stored it (across reconnections).

        Returns True if the server counted it now, False if it already had it.
        """
        self.assignments.pop(trip_id, None)
        self.finished.add(trip_id)
        fut = self._unconfirmed.get(trip_id)
        if fut is None:
            fut = asyncio.get_running_loop().create_future()
            self._unconfirmed[trip_id] = fut
        if self.connected and self._ws is not None:
            with contextlib.suppress(websockets.ConnectionClosed):
                await self._ws.send(json.dumps({"type": "done", "trip_id": trip_id}))
        return await asyncio.wait_for(asyncio.shield(fut), timeout_s)

    async def press_seat_button(self, seat: int, timeout_s: float = 10.0) -> dict[str, Any]:
        """A passenger asks to get off at the next appropriate stop; returns the server's seat_ack."""
        if self._ws is None:
            raise ConfigError(f"vehicle {self.vehicle_id!r}: seat button needs a connection, got none")
        fut: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._seat_waiters.append(fut)
        await self._ws.send(json.dumps({"type": "seat_button", "seat": seat}))
        return await asyncio.wait_for(fut, timeout_s)

    async def sync(self, timeout_s: float = 10.0) -> None:
        """Barrier: returns once the server has handled everything this client sent before and this
        client has handled everything the server queued to it before (a ping answered on the link's
        ordered queue). A simulator calls it to make what the vehicle knows a function of what it did,
        not of network timing."""
        if not self.connected or self._ws is None:
            raise ConfigError(f"vehicle {self.vehicle_id!r}: sync needs a resumed connection, got none")
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._pong_waiters.append(fut)
        await self._ws.send(json.dumps({"type": "ping"}))
        await asyncio.wait_for(fut, timeout_s)

    async def wait_for(self, predicate: Callable[[VehicleClient], bool], timeout_s: float = 10.0) -> None:
        """Wait until ``predicate(self)`` holds, re-checking after every message."""

        async def loop() -> None:
            while not predicate(self):
                self._changed.clear()
                await self._changed.wait()

        await asyncio.wait_for(loop(), timeout_s)
