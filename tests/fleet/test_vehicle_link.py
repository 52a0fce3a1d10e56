"""Against the real server process: a vehicle client streams status, gets assignments, drops its link
and resumes without losing or duplicating anything; the server survives a kill without losing data."""

from __future__ import annotations

import asyncio

import httpx
import pytest
import sqlalchemy as sa

from lastmile.core.errors import ConfigError
from lastmile.fleet.vehicle_client import VehicleClient
from tests.fleet.conftest import ServerProcess, db_engine


def _db_rows(server: ServerProcess, sql: str) -> list[tuple[object, ...]]:
    engine = db_engine(server)
    with engine.connect() as conn:
        rows = [tuple(r) for r in conn.execute(sa.text(sql))]
    engine.dispose()
    return rows


async def _start_vehicle(server: ServerProcess, vehicle_id: str) -> VehicleClient:
    client = VehicleClient(server.url, vehicle_id, server.tokens["vehicle"])
    await client.register()
    with server.client("operator") as op:
        assert (
            op.post(f"/api/vehicles/{vehicle_id}/command", json={"command": "start_service"}).status_code
            == 200
        )
    await client.start()
    # Parked at S1's bay, facing along the loop.
    assert await client.send_status(x_m=560.0, y_m=-6.5, yaw_rad=0.0, speed_mps=0.0, behaviour="dwell")
    return client


def test_a_dropped_vehicle_link_resumes_with_pending_trips_once_and_no_duplicates(
    durable_server: ServerProcess,
) -> None:
    server = durable_server

    async def scenario() -> None:
        client = await _start_vehicle(server, "shuttle-1")
        assert client.service == "in_service"
        with server.client("rider") as rider:
            first = rider.post("/api/rides", json={"origin": "S2", "destination": "S3"}).json()
            assert first["state"] == "assigned" and first["vehicle_id"] == "shuttle-1"
            assert first["eta_pickup_s"] > 0
            await client.wait_for(lambda c: len(c.assignments) == 2)
            client.drop_connection()
            # Made while the vehicle is away: it must arrive on resume, exactly once.
            second = rider.post("/api/rides", json={"origin": "S3", "destination": "S4"}).json()
            await client.wait_resumed()
            await client.wait_for(lambda c: len(c.assignments) == 4)
        assert client.stats.connections == 2
        assert client.stats.duplicates_ignored == 2  # the two trips of the first ride came again
        kinds = sorted((a.kind, a.request_id) for a in client.assignments.values())
        assert kinds == sorted(
            [
                ("pickup", first["id"]),
                ("dropoff", first["id"]),
                ("pickup", second["id"]),
                ("dropoff", second["id"]),
            ]
        )
        pickup = next(
            a for a in client.assignments.values() if a.kind == "pickup" and a.request_id == first["id"]
        )
        assert await client.complete(pickup.id) is True
        # The link drops right after the report: sending it again is recognised as already done.
        client.drop_connection()
        await client.wait_resumed()
        assert pickup.id not in client.assignments and client.stats.duplicates_ignored == 2 + 3
        with server.client("rider") as rider:
            assert rider.get(f"/api/rides/{first['id']}").json()["state"] == "picked_up"
        await client.stop()

    asyncio.run(scenario())
    done = _db_rows(server, "SELECT kind, request_id, state FROM trips ORDER BY id")
    assert len(done) == 4 and [r[2] for r in done].count("done") == 1
    events = _db_rows(server, "SELECT kind FROM events WHERE kind = 'picked_up'")
    assert len(events) == 1


def test_operator_commands_reach_the_vehicle_and_suspension_requeues_its_riders(
    fresh_server: ServerProcess,
) -> None:
    server = fresh_server

    async def scenario() -> None:
        client = await _start_vehicle(server, "shuttle-2")
        with server.client("rider") as rider, server.client("operator") as op:
            ride = rider.post("/api/rides", json={"origin": "S4", "destination": "S1"}).json()
            await client.wait_for(lambda c: len(c.assignments) == 2)
            res = op.post(
                "/api/vehicles/shuttle-2/command", json={"command": "emergency_stop", "reason": "test"}
            )
            assert res.json()["service"] == "emergency_stop"
            await client.wait_for(lambda c: c.service == "emergency_stop" and not c.assignments)
            assert client.stats.commands == ["emergency_stop"] and client.stats.cancels == 2
            after = rider.get(f"/api/rides/{ride['id']}").json()
            assert after["state"] == "waiting" and "emergency stop" in after["reason"]
            state = op.get("/api/vehicles/shuttle-2").json()
            assert state["behaviour"] == "dwell" and state["connected"] is True and state["x_m"] == 560.0
        await client.stop()

    asyncio.run(scenario())


def test_a_killed_server_restarts_on_the_same_database_without_losing_anything(
    durable_server: ServerProcess,
) -> None:
    server = durable_server

    async def before() -> tuple[list[str], int]:
        client = await _start_vehicle(server, "shuttle-3")
        with server.client("rider") as rider:
            ids = [
                rider.post("/api/rides", json={"origin": "S1", "destination": "S3"}).json()["id"]
                for _ in range(14)
            ]
        # Six seats, two laps of horizon: six riders now, six a lap later, two queued.
        await client.wait_for(lambda c: len(c.assignments) == 24)
        await client.stop()
        return ids, 24

    ids, n_trips = asyncio.run(before())
    server.kill()
    server.start()
    with server.client("rider") as rider, server.client("operator") as op:
        states = [rider.get(f"/api/rides/{i}").json()["state"] for i in ids]
        assert sorted(states) == ["assigned"] * 12 + ["waiting"] * 2
        assert op.get("/api/vehicles/shuttle-3").json()["service"] == "in_service"
        assert len(op.get("/api/events?limit=1000").json()) >= 10

    async def after() -> None:
        client = VehicleClient(server.url, "shuttle-3", server.tokens["vehicle"])
        await client.start()
        await client.wait_for(lambda c: len(c.assignments) == n_trips)
        assert client.service == "in_service"
        await client.stop()

    asyncio.run(after())


def test_a_vehicle_websocket_without_a_valid_token_is_refused(server: ServerProcess) -> None:
    async def scenario() -> None:
        client = VehicleClient(server.url, "auth-1", "bogus", reconnect_delay_s=0.05)
        with pytest.raises(ConfigError, match="4401"):
            await client.start()
        assert not client.connected and client.stats.assignments_received == 0
        await client.stop()
        rider = VehicleClient(server.url, "auth-1", server.tokens["rider"])
        with pytest.raises(ConfigError, match="4403"):
            await rider.start()
        await rider.stop()

    asyncio.run(scenario())
    assert httpx.get(server.url + "/openapi.json").status_code == 200


def test_seat_button_and_timetable_runs_reach_the_vehicle_as_trips(fresh_server: ServerProcess) -> None:
    server = fresh_server

    async def scenario() -> None:
        client = await _start_vehicle(server, "shuttle-4")
        # Driving east on the bottom straight 150 m before S1 at 4 m/s: S1 is the next stop it can make.
        assert await client.send_status(x_m=410.0, y_m=-1.75, yaw_rad=0.0, speed_mps=4.0, behaviour="cruise")
        await asyncio.sleep(0.3)
        ack = await client.press_seat_button(seat=3)
        assert ack["stop_id"] == "S1"
        await client.wait_for(lambda c: any(a.kind == "seat_stop" for a in c.assignments.values()))
        again = await client.press_seat_button(seat=5)  # a second press asks for the same stop once
        assert again["trip_id"] == ack["trip_id"]
        with server.client("operator") as op:
            res = op.post("/api/vehicles/shuttle-4/timetable-run", json={"run_id": "morning-0820"})
            assert res.status_code == 200
            assert [t["stop_id"] for t in res.json()] == ["S1", "S2", "S3", "S4", "S1"]
            assert (
                op.post("/api/vehicles/shuttle-4/timetable-run", json={"run_id": "morning-0820"}).status_code
                == 409
            )
            res = op.post("/api/vehicles/shuttle-4/timetable-run", json={"run_id": "midnight"})
            assert res.status_code == 404 and "'midnight'" in res.json()["detail"]
        await client.wait_for(lambda c: sum(a.kind == "timetable" for a in c.assignments.values()) == 5)
        with server.client("operator") as op:
            plan = op.get("/api/vehicles/shuttle-4").json()["plan"]
        # The seat-button stop and the run's first call share the next pass of S1.
        assert plan[0]["stop_id"] == "S1" and {t["kind"] for t in plan[0]["trips"]} == {
            "seat_stop",
            "timetable",
        }
        assert [v["stop_id"] for v in plan] == ["S1", "S2", "S3", "S4", "S1"]
        await client.stop()

    asyncio.run(scenario())
