"""The WebSocket side of the server: vehicle links (resumable) and live snapshots for the dashboard.

Each connection has its own outgoing queue and sender task, so messages to a vehicle leave in the
order the dispatcher made them and a slow browser never blocks the dispatcher.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
from typing import Any

from fastapi import WebSocket
from pydantic import BaseModel, Field, ValidationError
from starlette.websockets import WebSocketDisconnect

from lastmile.core.vehicle_messages import HMI_LIGHTS
from lastmile.fleet.dispatcher import Dispatcher

log = logging.getLogger(__name__)
SNAPSHOT_PERIOD_S = 0.2  # at most five dashboard updates a second
LIVE_QUEUE = 4  # snapshots a slow browser may lag before older ones are dropped


class HmiStatus(BaseModel):
    """What the vehicle's HMI shows now (see ``lastmile.stack.hmi``): the announced behaviour, the
    autonomy-state light, each screen's text and the last sound."""

    cue: str = Field(default="", max_length=40)
    light: str = ""
    front: str = Field(default="", max_length=120)
    rear: str = Field(default="", max_length=120)
    inside: str = Field(default="", max_length=120)
    sound: str = Field(default="", max_length=40)

    def check(self) -> None:
        if self.light not in HMI_LIGHTS:
            raise ValueError(f"hmi.light: expected one of {HMI_LIGHTS}, got {self.light!r}")


class StatusMsg(BaseModel):
    """A vehicle's status report (map frame: metres, radians counter-clockwise, m/s)."""

    x_m: float
    y_m: float
    yaw_rad: float = 0.0
    speed_mps: float = 0.0
    behaviour: str = ""
    health: str = "ok"
    passengers: int = 0
    door: str = "closed"
    hmi: HmiStatus | None = None

    def check(self) -> None:
        if self.hmi is not None:
            self.hmi.check()
        for name in ("x_m", "y_m", "yaw_rad", "speed_mps"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name}: expected a finite number, got {getattr(self, name)}")
        if not 0 <= self.passengers <= 64:
            raise ValueError(f"passengers: expected 0..64, got {self.passengers}")
        if self.door not in ("open", "closed", "opening", "closing"):
            raise ValueError(f"door: expected open, closed, opening or closing, got {self.door!r}")


async def handle_vehicle_message(d: Dispatcher, vehicle_id: str, raw: str) -> dict[str, Any] | None:
    """Apply one message from a vehicle; returns the reply to send, if any."""
    try:
        msg = json.loads(raw)
        kind = msg["type"]
    except (ValueError, KeyError, TypeError):
        return {"type": "error", "reason": f"expected a JSON object with a 'type', got {raw[:80]!r}"}
    try:
        if kind == "status":
            body = StatusMsg.model_validate({k: v for k, v in msg.items() if k != "type"})
            body.check()
            d.vehicle_status(vehicle_id, body.model_dump())
            return None
        if kind == "ack":
            await d.trip_ack(vehicle_id, int(msg["trip_id"]))
            return None
        if kind == "done":
            fresh = await d.trip_done(vehicle_id, int(msg["trip_id"]))
            return {"type": "done_ack", "trip_id": int(msg["trip_id"]), "duplicate": not fresh}
        if kind == "seat_button":
            trip = await d.seat_button(vehicle_id, int(msg.get("seat", 0)))
            return {"type": "seat_ack", "trip_id": trip["id"], "stop_id": trip["stop_id"]}
        if kind == "ping":
            return {"type": "pong"}
    except (ValidationError, ValueError, KeyError, TypeError) as exc:
        return {"type": "error", "reason": f"bad {kind!r} message: {exc}".replace("\n", " ")[:300]}
    return {
        "type": "error",
        "reason": f"unknown message type {str(kind)[:40]!r}: expected status, ack, done, seat_button, ping",
    }


class Hub:
    """Connected vehicles and dashboard viewers."""

    def __init__(self, dispatcher: Dispatcher) -> None:
        self.dispatcher = dispatcher
        self.vehicles: dict[str, tuple[WebSocket, asyncio.Queue[dict[str, Any] | None]]] = {}
        self.viewers: set[asyncio.Queue[str | None]] = set()
        self._task: asyncio.Task[None] | None = None

    def start(self) -> None:
        self._task = asyncio.create_task(self._broadcast())

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        for q in self.viewers:
            q.put_nowait(None)
        for ws, vq in list(self.vehicles.values()):
            vq.put_nowait(None)
            with contextlib.suppress(Exception):
                await ws.close(code=1001)

    def push_vehicle(self, vehicle_id: str, msg: dict[str, Any]) -> None:
        """Queue a message to a vehicle if it is connected; if not, it hears it when it resumes."""
        link = self.vehicles.get(vehicle_id)
        if link is not None:
            link[1].put_nowait(msg)

    async def _sender(self, ws: WebSocket, q: asyncio.Queue[Any]) -> None:
        while True:
            msg = await q.get()
            if msg is None:
                return
            await ws.send_text(msg if isinstance(msg, str) else json.dumps(msg))

    async def serve_vehicle(self, ws: WebSocket, vehicle_id: str) -> None:
        d = self.dispatcher
        old = self.vehicles.pop(vehicle_id, None)
        if old is not None:  # a resumed link replaces one the vehicle has given up on
            old[1].put_nowait(None)
            with contextlib.suppress(Exception):
                await old[0].close(code=4409, reason="replaced by a newer connection")
        q: asyncio.Queue[dict[str, Any] | None] = asyncio.Queue()
        q.put_nowait({"type": "welcome", "vehicle_id": vehicle_id})
        for msg in d.resume_messages(vehicle_id):
            q.put_nowait(msg)
        q.put_nowait({"type": "resumed"})
        self.vehicles[vehicle_id] = (ws, q)
        d.set_connected(vehicle_id, True)
        sender = asyncio.create_task(self._sender(ws, q))
        try:
            while True:
                raw = await ws.receive_text()
                reply = await handle_vehicle_message(d, vehicle_id, raw)
                if reply is not None:
                    q.put_nowait(reply)
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            sender.cancel()
            if self.vehicles.get(vehicle_id, (None,))[0] is ws:
                del self.vehicles[vehicle_id]
                d.set_connected(vehicle_id, False)

    async def serve_live(self, ws: WebSocket) -> None:
        q: asyncio.Queue[str | None] = asyncio.Queue(maxsize=LIVE_QUEUE)
        q.put_nowait(json.dumps(self.dispatcher.snapshot()))
        self.viewers.add(q)
        sender = asyncio.create_task(self._sender(ws, q))
        try:
            while True:
                await ws.receive_text()  # viewers only listen; this notices when they leave
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            self.viewers.discard(q)
            sender.cancel()

    async def _broadcast(self) -> None:
        changed = self.dispatcher.changed
        while True:
            await changed.wait()
            changed.clear()
            if self.viewers:
                text = json.dumps(self.dispatcher.snapshot())
                for q in list(self.viewers):
                    if q.full():
                        with contextlib.suppress(asyncio.QueueEmpty):
                            q.get_nowait()
                    q.put_nowait(text)
            await asyncio.sleep(SNAPSHOT_PERIOD_S)
