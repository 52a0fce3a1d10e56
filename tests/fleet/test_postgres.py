"""PostgreSQL specifics. The restart, resume and three-shuttle tests run on both databases
(``durable_server`` in conftest); here: the password of a real PostgreSQL URL never reaches the log,
and an old database's idempotency constraint is upgraded on PostgreSQL too.

The server is a private ``initdb`` cluster on a free loopback port with password authentication
(``tests/fleet/pg_cluster.py``), or ``LASTMILE_FLEET_PG_URL``; skipped with the reason only if neither
can be had."""

from __future__ import annotations

from pathlib import Path

import pytest
import sqlalchemy as sa

from lastmile.fleet import storage
from tests.fleet.conftest import ServerProcess
from tests.fleet.pg_cluster import ExternalPg, PgCluster


def test_the_database_password_is_hidden_in_the_start_line_and_log(
    tmp_path: Path, postgres: PgCluster | ExternalPg
) -> None:
    if not postgres.password:
        pytest.skip("LASTMILE_FLEET_PG_URL has no password to hide")
    url = postgres.new_database()
    server = ServerProcess(out_dir=tmp_path / "serve", runs_dir=tmp_path / "runs", db_url=url).start()
    try:
        with server.client("rider") as rider:
            assert rider.post("/api/rides", json={"origin": "S1", "destination": "S2"}).status_code == 201
    finally:
        server.stop()
    log = server.log_text()
    assert "lastmile serve: http://127.0.0.1" in log and ":***@127.0.0.1" in log
    assert postgres.password not in log


def test_an_old_postgres_database_gets_its_idempotency_keys_scoped_per_rider(
    postgres: PgCluster | ExternalPg,
) -> None:
    engine = storage.make_engine(postgres.new_database())
    legacy = sa.MetaData()
    sa.Table(
        "ride_requests",
        legacy,
        *[
            sa.Column(c.name, c.type, primary_key=c.primary_key, unique=c.name == "client_ref")
            for c in storage.ride_requests.columns
        ],
    )
    legacy.create_all(engine)
    row = {c.name: None for c in storage.ride_requests.columns} | {
        "id": "r1",
        "client_ref": "k",
        "rider": "alice",
        "origin": "S1",
        "destination": "S2",
        "seats": 1,
        "state": "waiting",
        "created_us": 1,
    }
    with engine.begin() as conn:
        conn.execute(storage.ride_requests.insert(), row)
    with engine.begin() as conn:
        assert storage.scope_idempotency_keys(conn) is True
    with engine.begin() as conn:
        assert storage.scope_idempotency_keys(conn) is False
        conn.execute(storage.ride_requests.insert(), row | {"id": "r2", "rider": "bob"})
    with pytest.raises(sa.exc.IntegrityError), engine.begin() as conn:
        conn.execute(storage.ride_requests.insert(), row | {"id": "r3"})
    engine.dispose()
