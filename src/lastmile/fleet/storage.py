"""The dispatch database (SQLAlchemy Core): tables, and a writer thread that group-commits.

Every change the server makes is a small function of a connection queued to one writer thread. The
writer takes everything queued, runs it in one transaction, commits once, and only then tells the
waiting requests they may answer (if a write fails, the batch is redone one write per commit, so only
the bad one fails). So a reply always means "on disk" (SQLite in WAL mode with
``synchronous=FULL``, or PostgreSQL), while one fsync is shared by every request that arrived during
the previous one: that is what lets a single SQLite file take hundreds of ride requests per second.
"""

from __future__ import annotations

import asyncio
import logging
import queue
import re
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    Column,
    Connection,
    Engine,
    Float,
    Integer,
    MetaData,
    String,
    Table,
    UniqueConstraint,
    create_engine,
    event,
    inspect,
)
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError

from lastmile.core.errors import ConfigError

log = logging.getLogger(__name__)
metadata = MetaData()

vehicles = Table(
    "vehicles",
    metadata,
    Column("id", String(64), primary_key=True),
    Column("name", String(128), nullable=False),
    Column("capacity", Integer, nullable=False),
    Column("service", String(32), nullable=False),  # out_of_service | in_service | suspended | emergency_stop
    Column("x_m", Float),
    Column("y_m", Float),
    Column("yaw_rad", Float),
    Column("speed_mps", Float),
    Column("route_s_m", Float),
    Column("behaviour", String(64)),
    Column("health", String(32)),
    Column("passengers", Integer, nullable=False, default=0),
    Column("door", String(16)),
    Column("last_status_us", BigInteger),
    Column("registered_us", BigInteger, nullable=False),
)

stops = Table(
    "stops",
    metadata,
    Column("id", String(16), primary_key=True),
    Column("name", String(128), nullable=False),
    Column("x_m", Float, nullable=False),
    Column("y_m", Float, nullable=False),
    Column("route_s_m", Float, nullable=False),
)

timetable = Table(
    "timetable",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("run_id", String(32), nullable=False, index=True),
    Column("shift", String(16), nullable=False),
    Column("seq", Integer, nullable=False),
    Column("stop_id", String(16), nullable=False),
    Column("time_s", Float, nullable=False),
)

ride_requests = Table(
    "ride_requests",
    metadata,
    Column("id", String(32), primary_key=True),
    # Idempotency key, unique per rider (two riders may pick the same key): see the constraint below.
    Column("client_ref", String(64)),
    Column("rider", String(64), nullable=False),
    Column("origin", String(16), nullable=False),
    Column("destination", String(16), nullable=False),
    Column("seats", Integer, nullable=False),
    Column("state", String(16), nullable=False, index=True),
    Column("vehicle_id", String(64)),
    Column("created_us", BigInteger, nullable=False),
    Column("eta_pickup_us", BigInteger),
    Column("eta_dropoff_us", BigInteger),
    Column("picked_up_us", BigInteger),
    Column("dropped_off_us", BigInteger),
    Column("closed_us", BigInteger),
    Column("reason", String(256)),
    UniqueConstraint("rider", "client_ref", name="uq_ride_requests_rider_ref"),
)

# A trip is one task handed to a vehicle: a pick-up, a drop-off, a timetable call or a seat-button stop.
trips = Table(
    "trips",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("vehicle_id", String(64), nullable=False, index=True),
    Column("kind", String(16), nullable=False),
    Column("stop_id", String(16), nullable=False),
    Column("request_id", String(32)),
    Column("run_id", String(32)),
    Column("seats", Integer, nullable=False),
    Column("visit", Integer, nullable=False),  # order of the stop visit in the vehicle's plan
    Column("state", String(16), nullable=False, index=True),  # pending | acked | done | cancelled
    Column("created_us", BigInteger, nullable=False),
    Column("done_us", BigInteger),
)

events = Table(
    "events",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("stamp_us", BigInteger, nullable=False),
    Column("kind", String(32), nullable=False),
    Column("vehicle_id", String(64)),
    Column("request_id", String(32)),
    Column("detail", JSON),
)

tokens = Table(
    "tokens",
    metadata,
    Column("sha256", String(64), primary_key=True),
    Column("role", String(16), nullable=False),
    Column("subject", String(64), nullable=False),
    Column("created_us", BigInteger, nullable=False),
    Column("revoked", Boolean, nullable=False, default=False),
)


def _legacy_ref_constraints(conn: Connection) -> list[str]:
    """Names of unique constraints on ``client_ref`` alone (SQLite: its automatic index names)."""
    if conn.dialect.name == "sqlite":
        # The inspector misses a column's inline UNIQUE; SQLite's own index list names every one.
        names = [
            row[1]
            for row in conn.exec_driver_sql("PRAGMA index_list(ride_requests)")
            if row[2] and row[3] == "u"
        ]
        return [
            n
            for n in names
            if [r[2] for r in conn.exec_driver_sql(f"PRAGMA index_info('{n}')")] == ["client_ref"]
        ]
    uniques = inspect(conn).get_unique_constraints("ride_requests")
    return [str(u["name"]) for u in uniques if u["column_names"] == ["client_ref"]]


def scope_idempotency_keys(conn: Connection) -> bool:
    """Databases made before keys were scoped per rider have ``client_ref`` unique on its own, which
    makes a second rider's request with the same key fail: replace that constraint by (rider,
    client_ref). Returns whether anything changed. SQLite cannot drop a constraint, so the table is
    rebuilt (rename, create, copy, drop) inside the caller's transaction."""
    insp = inspect(conn)
    if not insp.has_table("ride_requests"):
        return False
    legacy = _legacy_ref_constraints(conn)
    if not legacy:
        return False
    log.warning("database: scoping ride idempotency keys per rider (one-time upgrade of ride_requests)")
    if conn.dialect.name == "sqlite":
        indexes = [i["name"] for i in insp.get_indexes("ride_requests") if i["name"]]
        conn.exec_driver_sql("ALTER TABLE ride_requests RENAME TO ride_requests_legacy")
        for name in indexes:  # they moved with the table; their names are needed by the new one
            conn.exec_driver_sql(f'DROP INDEX IF EXISTS "{name}"')
        ride_requests.create(conn)
        cols = ", ".join(c.name for c in ride_requests.columns)
        conn.exec_driver_sql(f"INSERT INTO ride_requests ({cols}) SELECT {cols} FROM ride_requests_legacy")
        conn.exec_driver_sql("DROP TABLE ride_requests_legacy")
        return True
    for name in legacy:
        conn.exec_driver_sql(f'ALTER TABLE ride_requests DROP CONSTRAINT "{name}"')
    # Plain DDL: SQLAlchemy's AddConstraint would mark the table's own constraint as added separately,
    # and every later CREATE TABLE of ride_requests in this process would then leave it out.
    conn.exec_driver_sql(
        "ALTER TABLE ride_requests ADD CONSTRAINT uq_ride_requests_rider_ref UNIQUE (rider, client_ref)"
    )
    return True


def redact_url(url: str) -> str:
    """``url`` with its password replaced by ``***`` (for logs, the start line and error messages)."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except (ArgumentError, ValueError):
        # Not parseable as a URL: still hide whatever sits between "user:" and "@".
        return re.sub(r"(//[^:/@]*:)[^@]*@", r"\1***@", url)


def default_sqlite_url(out_dir: Path) -> str:
    out_dir.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{(out_dir / 'fleet.db').resolve()}"


def make_engine(url: str) -> Engine:
    """An engine for ``url``: SQLite gets WAL and full fsync on commit; PostgreSQL needs psycopg.

    Raises:
        ConfigError: the URL names neither SQLite nor PostgreSQL, is malformed, or its driver is not
            installed (the message shows the URL with its password hidden).
    """
    shown = redact_url(url)
    if url.startswith("sqlite"):
        try:
            engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})
        except (ArgumentError, ValueError):
            raise ConfigError(f"database URL: expected sqlite:///PATH, got {shown!r}") from None

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn: Any, _record: Any) -> None:
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=FULL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()

        return engine
    if url.startswith(("postgresql", "postgres")):
        if url.startswith("postgres://"):
            url = "postgresql://" + url[len("postgres://") :]
        if url.startswith("postgresql://"):
            url = "postgresql+psycopg://" + url[len("postgresql://") :]
        try:
            return create_engine(url, pool_pre_ping=True)
        except ModuleNotFoundError as exc:
            raise ConfigError(
                f"database {shown!r}: expected the psycopg driver (pip install 'lastmile[postgres]'), "
                f"got {exc}"
            ) from None
        except (ArgumentError, ValueError):
            raise ConfigError(
                f"database URL: expected postgresql://USER:PASSWORD@HOST:PORT/DB, got {shown!r}"
            ) from None
    raise ConfigError(f"database URL: expected sqlite:///PATH or postgresql://..., got {shown!r}")


def check_connection(engine: Engine) -> None:
    """Connect once, so an unreachable server, a wrong password or a missing folder is one line at
    start instead of a traceback at the first request.

    Raises:
        ConfigError: naming the database (password hidden) and the driver's reason.
    """
    try:
        with engine.connect():
            pass
    except SQLAlchemyError as exc:
        reason = str(getattr(exc, "orig", None) or exc).strip().splitlines()
        password = engine.url.password
        text = reason[0] if reason else type(exc).__name__
        if password:
            text = text.replace(str(password), "***")
        shown = engine.url.render_as_string(hide_password=True)
        raise ConfigError(f"database {shown!r}: expected to connect, got {text}") from None


Op = Callable[[Connection], Any]


@dataclass(frozen=True, slots=True)
class InsertRows:
    """Plain inserts a writer may send as one executemany per table with the rest of its batch.

    They go before the batch's other writes: safe because no write here ever depends on a row being
    absent, and updates that follow an insert in time also follow it in the batch.
    """

    rows: tuple[tuple[Table, dict[str, Any]], ...]


class Writer:
    """One thread that owns all writes and commits them in groups.

    ``submit(op)`` returns an awaitable resolved with ``op``'s result after the commit that included it
    (or with the exception ``op`` raised; a failing op fails alone).
    """

    def __init__(self, engine: Engine, max_batch: int = 512) -> None:
        self.engine = engine
        self.max_batch = max_batch
        self._queue: queue.SimpleQueue[tuple[Op | InsertRows, asyncio.Future[Any] | None] | None] = (
            queue.SimpleQueue()
        )
        self._thread = threading.Thread(target=self._run, name="fleet-db-writer", daemon=True)
        self._loop: asyncio.AbstractEventLoop | None = None
        self.commits = 0
        self.ops = 0

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._thread.start()

    def submit(self, op: Op | InsertRows) -> asyncio.Future[Any]:
        assert self._loop is not None, "Writer.start() first"
        fut: asyncio.Future[Any] = self._loop.create_future()
        self._queue.put((op, fut))
        return fut

    def submit_nowait(self, op: Op) -> None:
        """Queue a write nobody waits for (vehicle status): it still commits in order."""
        self._queue.put((op, None))

    def stop(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=30)

    def _resolve(self, fut: asyncio.Future[Any] | None, ok: bool, value: Any) -> None:
        if fut is None or fut.done():
            return
        if ok:
            fut.set_result(value)
        else:
            fut.set_exception(value)

    def _commit(
        self, batch: list[tuple[Op | InsertRows, asyncio.Future[Any] | None]]
    ) -> list[tuple[Any, bool, Any]]:
        with self.engine.begin() as conn:
            bulk: dict[Table, list[dict[str, Any]]] = {}
            for op, _ in batch:
                if isinstance(op, InsertRows):
                    for table, row in op.rows:
                        bulk.setdefault(table, []).append(row)
            for table, rows in bulk.items():
                conn.execute(table.insert(), rows)
            return [(fut, True, None if isinstance(op, InsertRows) else op(conn)) for op, fut in batch]

    def _run(self) -> None:
        stopping = False
        while not stopping:
            first = self._queue.get()
            if first is None:
                break
            batch = [first]
            while len(batch) < self.max_batch:
                try:
                    nxt = self._queue.get_nowait()
                except queue.Empty:
                    break
                if nxt is None:
                    stopping = True
                    break
                batch.append(nxt)
            try:
                results = self._commit(batch)
            except Exception:
                # One bad write must not sink the writes it shared a commit with: redo them one by one.
                results = []
                for item in batch:
                    try:
                        results.extend(self._commit([item]))
                    except Exception as exc:
                        log.warning("database write failed: %s", exc)
                        results.append((item[1], False, exc))
            self.commits += 1
            self.ops += len(batch)
            loop = self._loop
            if loop is not None and not loop.is_closed():
                for fut, ok, value in results:
                    if fut is not None:
                        loop.call_soon_threadsafe(self._resolve, fut, ok, value)
