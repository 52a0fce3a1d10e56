"""The same server on PostgreSQL: rides, trips and vehicles survive a SIGKILL and restart.

Needs a server to point at: set LASTMILE_FLEET_PG_URL (e.g. postgresql://postgres@127.0.0.1:5432/fleet_test,
a database this test may empty) and install the ``postgres`` extra; otherwise it is skipped."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import pytest

from lastmile.fleet.vehicle_client import VehicleClient
from tests.fleet.conftest import ServerProcess

PG_URL = os.environ.get("LASTMILE_FLEET_PG_URL")


def test_postgres_backend_keeps_everything_across_a_kill(tmp_path: Path) -> None:
    if not PG_URL:
        pytest.skip("LASTMILE_FLEET_PG_URL is not set: no PostgreSQL server to test against")
    pytest.importorskip("psycopg", reason="the postgres extra (psycopg) is not installed")
    from lastmile.fleet import storage

    engine = storage.make_engine(PG_URL)
    storage.metadata.drop_all(engine)
    engine.dispose()
    (tmp_path / "runs").mkdir()
    (tmp_path / "serve").mkdir()
    server = ServerProcess(out_dir=tmp_path / "serve", runs_dir=tmp_path / "runs", db_url=PG_URL).start()
    try:

        async def before() -> list[str]:
            client = VehicleClient(server.url, "pg-1", server.tokens["vehicle"])
            await client.register()
            with server.client("operator") as op:
                op.post("/api/vehicles/pg-1/command", json={"command": "start_service"}).raise_for_status()
            await client.start()
            with server.client("rider") as rider:
                ids = [
                    rider.post("/api/rides", json={"origin": "S2", "destination": "S4"}).json()["id"]
                    for _ in range(3)
                ]
            await client.wait_for(lambda c: len(c.assignments) == 6)
            pickup = next(a for a in client.assignments.values() if a.kind == "pickup")
            assert await client.complete(pickup.id)
            await client.stop()
            return ids

        ids = asyncio.run(before())
        server.kill()
        server.start()
        with server.client("rider") as rider, server.client("operator") as op:
            states = sorted(rider.get(f"/api/rides/{i}").json()["state"] for i in ids)
            assert states == ["assigned", "assigned", "picked_up"]
            assert op.get("/api/vehicles/pg-1").json()["service"] == "in_service"
            kinds = [e["kind"] for e in op.get("/api/events?limit=1000").json()]
            assert kinds.count("ride_requested") == 3 and kinds.count("picked_up") == 1
    finally:
        server.stop()
