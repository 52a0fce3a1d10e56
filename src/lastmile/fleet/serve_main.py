"""``lastmile serve``: check the address, port and database before anything starts, then run uvicorn.

Everything a user can get wrong is one line and a non-zero exit (``ConfigError``), and the database
URL is shown with its password hidden, in the start line, in errors and in every log record.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
from collections.abc import Callable
from pathlib import Path

from lastmile.core.errors import ConfigError
from lastmile.fleet.storage import check_connection, default_sqlite_url, make_engine, redact_url

WS_MAX_MESSAGE_BYTES = 65_536
"""Largest WebSocket message a vehicle or dashboard may send (uvicorn's default is 16 MB; the largest
legitimate message, a status with its HMI texts, is under 2 kB)."""


def validate_port(port: int) -> int:
    """Raises ConfigError unless ``port`` is a TCP port 1-65535 (0 would let the OS pick one the
    start line could not name)."""
    if not 1 <= port <= 65535:
        raise ConfigError(f"--port: expected a TCP port 1-65535, got {port}")
    return port


def listen_socket(host: str, port: int) -> socket.socket:
    """A bound, listening TCP socket for ``host:port``, so a bad address or a port in use is one line
    here, before the database is opened, and uvicorn serves on exactly what the start line says.

    Raises:
        ConfigError: the port is out of range, the host is not an address or a resolvable name, or
            the address cannot be bound.
    """
    validate_port(port)
    try:
        family = socket.AF_INET6 if ipaddress.ip_address(host).version == 6 else socket.AF_INET
    except ValueError:
        try:
            family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
        except (socket.gaierror, UnicodeError) as exc:
            raise ConfigError(
                f"--host: expected an IP address or a resolvable name, got {host!r} ({exc})"
            ) from None
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(2048)
    except OSError as exc:
        sock.close()
        raise ConfigError(
            f"--host/--port: expected to listen on {host}:{port}, got {exc.strerror or exc}"
        ) from None
    sock.set_inheritable(True)
    return sock


class _RedactFilter(logging.Filter):
    """Replaces a secret in every log record (message and arguments) by ``***``."""

    def __init__(self, secret: str) -> None:
        super().__init__()
        self.secret = secret

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if self.secret in text:
            record.msg = text.replace(self.secret, "***")
            record.args = None
        if record.exc_info and record.exc_info[1] is not None and self.secret in str(record.exc_info[1]):
            record.exc_info = None
            record.msg = f"{record.msg} (traceback withheld: it holds the database password)"
        return True


def _redact_logs(secret: str) -> None:
    redact = _RedactFilter(secret)
    handlers = [logging.lastResort] if logging.lastResort is not None else []
    for name in ("", "uvicorn", "uvicorn.error", "uvicorn.access"):
        handlers += logging.getLogger(name).handlers
    for handler in handlers:
        handler.addFilter(redact)


def serve(
    *,
    host: str,
    port: int,
    db: str | None,
    out: Path,
    runs: Path,
    timetable_lead_s: float,
    announce: Callable[[str], None],
    route: Path | None = None,
) -> None:
    """Validate everything, then serve until interrupted.

    Raises:
        ConfigError: a bad address, port or database (one line, password hidden); a bad route file.
        MapError, RoutingError: the route's map or its stops (see ``hdmap.service_route.load_route``).
    """
    import uvicorn

    from lastmile.fleet.server import ServerConfig, create_app
    from lastmile.hdmap.service_route import load_route

    service = load_route(route) if route is not None else None  # a bad route is one line, before binding
    sock = listen_socket(host, port)
    try:
        url = db or default_sqlite_url(out)
        engine = make_engine(url)
        try:
            check_connection(engine)
        finally:
            engine.dispose()
        announce(
            f"lastmile serve: http://{host}:{port}/ (database {redact_url(url)}; "
            f"first-start tokens in {out}/tokens.json; service {service.name if service else 'campus'})"
        )
        config = ServerConfig(
            db_url=url, out_dir=out, runs_dir=runs, timetable_lead_s=timetable_lead_s, route=service
        )
        # uvicorn.Config sets up logging; the filter goes on the handlers after that, since a filter on
        # a logger misses what its children propagate.
        server = uvicorn.Server(
            uvicorn.Config(
                create_app(config),
                log_level="warning",
                access_log=False,
                ws_max_size=WS_MAX_MESSAGE_BYTES,
            )
        )
        if engine.url.password:
            _redact_logs(str(engine.url.password))
        server.run(sockets=[sock])
    finally:
        sock.close()
