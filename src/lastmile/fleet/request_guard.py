"""What stands between a client and the routes: body size and time limits, strict JSON numbers.

A pure ASGI middleware, so it sees the body as it streams in, before FastAPI buffers and parses it:

- a ``Content-Length`` above ``max_body_bytes`` is refused with 413 before one byte is read, and a
  chunked body is refused the moment its running total passes the limit (the server never holds more
  than the limit in memory, and never spends the event loop parsing a 20 MB document);
- a body that has not fully arrived ``body_timeout_s`` after its request started is refused with 408
  (a client sending one byte a second holds a connection, not the server);
- a JSON body must be strict JSON: ``NaN``, ``Infinity`` and numbers that overflow a double
  (``1e309``) are 422 with one line naming the token, instead of reaching pydantic as ``nan`` / ``inf``.

No error ever echoes the body back (the validation handler in ``server`` strips pydantic's ``input``).
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from fastapi import Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

MAX_INT_DIGITS = 19
"""Longest integer literal accepted (int64 has 19 digits); Python would otherwise spend quadratic time
converting a 60,000-digit literal, and no field of the API holds more."""


class BodyRejectedError(Exception):
    """A request the guard refuses: an HTTP status, a one-line reason, extra headers."""

    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.headers = headers or {}


def _reject_constant(name: str) -> Any:
    raise BodyRejectedError(422, f"JSON body: expected finite numbers, got {name}")


def _strict_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise BodyRejectedError(
            422, f"JSON body: expected a number within double range, got {text[:32]!r} (overflows)"
        )
    return value


def _strict_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise BodyRejectedError(
            422, f"JSON body: expected an integer of at most {MAX_INT_DIGITS} digits, got {len(text)} chars"
        )
    return int(text)


def check_strict_json(body: bytes) -> None:
    """Raise ``BodyRejectedError`` (422) if ``body`` holds NaN, Infinity or an out-of-range number.

    Malformed JSON passes through: FastAPI answers it with its own 422 (``json_invalid``).
    """
    try:
        json.loads(body, parse_constant=_reject_constant, parse_float=_strict_float, parse_int=_strict_int)
    except (ValueError, RecursionError):
        return


def _is_json(scope: Scope) -> bool:
    """A JSON content type, or none at all (FastAPI parses a body without one as JSON too)."""
    for name, value in scope.get("headers", ()):
        if name == b"content-type":
            media = value.split(b";", 1)[0].strip().lower()
            return media == b"application/json" or media.endswith(b"+json")
    return True


def _content_length(scope: Scope) -> int | None:
    for name, value in scope.get("headers", ()):
        if name == b"content-length":
            try:
                return int(value)
            except ValueError:
                return None
    return None


class RequestGuard:
    """ASGI middleware: admission (the per-token rate limit), size limit (413), body deadline (408),
    strict JSON numbers (422), in that order: a request refused early costs nothing more.

    Args:
        app: the application behind the guard.
        max_body_bytes: largest body accepted (the API's largest legitimate body is under 1 kB).
        body_timeout_s: time allowed for the whole body to arrive.
        admit: called with the scope before anything is read; raises ``BodyRejectedError`` to refuse.
    """

    def __init__(
        self,
        app: ASGIApp,
        *,
        max_body_bytes: int,
        body_timeout_s: float,
        admit: Callable[[Scope], None] | None = None,
    ) -> None:
        self.app = app
        self.max_body_bytes = max_body_bytes
        self.body_timeout_s = body_timeout_s
        self.admit = admit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        try:
            if self.admit is not None:
                self.admit(scope)
            body = await self._read_body(scope, receive)
            if body and _is_json(scope):
                check_strict_json(body)
        except BodyRejectedError as exc:
            await _send_error(send, exc)
            return
        delivered = False

        async def replay() -> Message:
            nonlocal delivered
            if not delivered:
                delivered = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)

    async def _read_body(self, scope: Scope, receive: Receive) -> bytes:
        declared = _content_length(scope)
        if declared is not None and declared > self.max_body_bytes:
            raise BodyRejectedError(
                413,
                f"request body too large: expected at most {self.max_body_bytes} bytes, "
                f"got Content-Length {declared}",
            )
        chunks: list[bytes] = []
        size = 0
        try:
            async with asyncio.timeout(self.body_timeout_s):
                while True:
                    message = await receive()
                    if message["type"] == "http.disconnect":
                        break
                    chunk = message.get("body", b"")
                    size += len(chunk)
                    if size > self.max_body_bytes:
                        raise BodyRejectedError(
                            413,
                            f"request body too large: expected at most {self.max_body_bytes} bytes, "
                            f"got more than that",
                        )
                    chunks.append(chunk)
                    if not message.get("more_body", False):
                        break
        except TimeoutError:
            raise BodyRejectedError(
                408,
                f"request body too slow: expected it complete within {self.body_timeout_s:g} s, "
                f"got {size} bytes by then",
            ) from None
        return b"".join(chunks)


async def _send_error(send: Send, exc: BodyRejectedError) -> None:
    payload = json.dumps({"detail": exc.detail}).encode()
    # The body may still be arriving: close the connection rather than read the rest of it.
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(payload)).encode()),
        (b"connection", b"close"),
        *((k.lower().encode(), v.encode()) for k, v in exc.headers.items()),
    ]
    await send({"type": "http.response.start", "status": exc.status, "headers": headers})
    await send({"type": "http.response.body", "body": payload})


async def validation_error_without_input(_request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422 handler, replaced: each error's location, message and type, never the input (a
    20 MB document would come back whole, and a NaN in it would make the answer unserialisable)."""
    if not isinstance(exc, RequestValidationError):
        raise exc
    errors = [
        {"loc": list(e.get("loc", ())), "msg": str(e.get("msg", ""))[:200], "type": str(e.get("type", ""))}
        for e in exc.errors()[:20]
    ]
    return JSONResponse({"detail": errors}, status_code=status.HTTP_422_UNPROCESSABLE_ENTITY)
