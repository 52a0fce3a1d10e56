"""Against the real server process: every call needs a token of the right role; bad input is a clear 4xx."""

from __future__ import annotations

import json

import httpx
import pytest

from tests.fleet.conftest import ServerProcess


def test_openapi_schema_is_served_and_lists_the_ride_api(server: ServerProcess) -> None:
    schema = httpx.get(server.url + "/openapi.json").json()
    assert "/api/rides" in schema["paths"]
    assert "HTTPBearer" in schema["components"]["securitySchemes"]


@pytest.mark.parametrize("path", ["/api/stops", "/api/map", "/api/vehicles", "/api/runs", "/api/rides"])
def test_a_request_without_a_token_is_401(server: ServerProcess, path: str) -> None:
    res = httpx.get(server.url + path)
    assert res.status_code == 401
    assert "bearer token" in res.json()["detail"]


def test_an_unknown_token_is_401(server: ServerProcess) -> None:
    res = httpx.get(server.url + "/api/stops", headers={"Authorization": "Bearer not-a-token"})
    assert res.status_code == 401
    assert "invalid bearer token" in res.json()["detail"]


def test_a_rider_cannot_command_a_vehicle_or_see_the_fleet(server: ServerProcess) -> None:
    with server.client("operator") as op, server.client("rider") as rider:
        assert op.post("/api/vehicles", json={"id": "auth-1"}).status_code in (200, 201)
        res = rider.post("/api/vehicles/auth-1/command", json={"command": "emergency_stop"})
        assert res.status_code == 403
        assert "rider" in res.json()["detail"]
        assert rider.get("/api/vehicles").status_code == 403
        assert rider.get("/api/runs").status_code == 403
        assert op.get("/api/vehicles/auth-1").json()["service"] == "out_of_service"


def test_a_vehicle_token_cannot_request_rides_and_an_operator_can_command(server: ServerProcess) -> None:
    with server.client("vehicle") as veh, server.client("operator") as op:
        assert veh.post("/api/rides", json={"origin": "S1", "destination": "S2"}).status_code == 403
        assert op.post("/api/vehicles", json={"id": "auth-2"}).status_code in (200, 201)
        res = op.post("/api/vehicles/auth-2/command", json={"command": "emergency_stop", "reason": "test"})
        assert res.status_code == 200 and res.json()["service"] == "emergency_stop"
        # An emergency stop must be released before service can start again.
        assert op.post("/api/vehicles/auth-2/command", json={"command": "start_service"}).status_code == 409


def test_unknown_stop_ids_are_named_in_the_error(server: ServerProcess) -> None:
    with server.client("rider") as rider:
        res = rider.post("/api/rides", json={"origin": "S9", "destination": "S2"})
        assert res.status_code == 404
        assert "'S9'" in res.json()["detail"] and "S1" in res.json()["detail"]
        res = rider.post("/api/rides", json={"origin": "S1", "destination": "Nowhere"})
        assert res.status_code == 404 and "'Nowhere'" in res.json()["detail"]


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        ({"origin": "S1", "destination": "S1"}, "other than the origin"),
        ({"origin": "S1", "destination": "S2", "seats": 7}, "less than or equal to 6"),
        ({"origin": "S1", "destination": "S2", "seats": 0}, "greater than or equal to 1"),
        ({"origin": "S1"}, "destination"),
        ({"origin": "S1", "destination": "S2", "colour": "red"}, "colour"),
        ({"origin": "S1;drop", "destination": "S2"}, "pattern"),
    ],
)
def test_bad_ride_requests_are_422_with_the_reason(
    server: ServerProcess, body: dict[str, object], needle: str
) -> None:
    with server.client("rider") as rider:
        res = rider.post("/api/rides", json=body)
    assert res.status_code == 422
    assert needle in res.text


def test_malformed_json_is_a_4xx_not_a_server_error(server: ServerProcess) -> None:
    with server.client("rider") as rider:
        res = rider.post("/api/rides", content=b"{not json", headers={"Content-Type": "application/json"})
    assert res.status_code == 422


def test_cancelling_twice_is_a_conflict_and_unknown_ids_are_404(server: ServerProcess) -> None:
    with server.client("rider") as rider:
        ride = rider.post("/api/rides", json={"origin": "S2", "destination": "S3"}).json()
        assert rider.delete(f"/api/rides/{ride['id']}").json()["state"] == "cancelled"
        res = rider.delete(f"/api/rides/{ride['id']}")
        assert res.status_code == 409 and "cancelled" in res.json()["detail"]
        assert rider.get("/api/rides/nope").status_code == 404
    with server.client("operator") as op:
        res = op.post("/api/vehicles/ghost/command", json={"command": "start_service"})
        assert res.status_code == 404 and "'ghost'" in res.json()["detail"]


def test_a_retried_request_with_the_same_client_ref_is_one_ride(server: ServerProcess) -> None:
    body = {"origin": "S1", "destination": "S3", "client_ref": "retry-42"}
    with server.client("rider") as rider:
        first = rider.post("/api/rides", json=body)
        again = rider.post("/api/rides", json=body)
    assert first.status_code == 201 and again.status_code == 200
    assert first.json()["id"] == again.json()["id"]


def test_operators_browse_and_download_recorded_runs(server: ServerProcess) -> None:
    with server.client("operator") as op:
        runs = op.get("/api/runs").json()
        assert [r["name"] for r in runs] == ["run-a"] and runs[0]["files"] == ["report.md"]
        assert op.get("/api/runs/run-a/files/report.md").text == "# a run\n"
        assert op.get("/api/runs/run-a/archive").content[:2] == b"PK"
        assert op.get("/api/runs/run-a/files/..%2F..%2Fetc%2Fpasswd").status_code == 404


def test_a_rider_sees_only_their_own_rides(server: ServerProcess) -> None:
    with server.client("operator") as op, server.client("rider") as alice:
        res = op.post("/api/tokens", json={"role": "rider", "subject": "bob"})
        assert res.status_code == 201
        bob_token = res.json()["token"]
        assert alice.post("/api/tokens", json={"role": "operator", "subject": "eve"}).status_code == 403
        ride = alice.post("/api/rides", json={"origin": "S3", "destination": "S1"}).json()
    with httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {bob_token}"}) as bob:
        assert bob.get("/api/whoami").json() == {"role": "rider", "subject": "bob"}
        res = bob.get(f"/api/rides/{ride['id']}")
        assert res.status_code == 403 and "another rider" in res.json()["detail"]
        assert bob.delete(f"/api/rides/{ride['id']}").status_code == 403
        assert all(r["id"] != ride["id"] for r in bob.get("/api/rides").json())


def test_bad_vehicle_messages_get_an_error_reply_and_the_link_stays_up(server: ServerProcess) -> None:
    from websockets.sync.client import connect

    with server.client("operator") as op:
        assert op.post("/api/vehicles", json={"id": "bad-msgs"}).status_code in (200, 201)
    url = server.url.replace("http", "ws") + "/ws/vehicle/bad-msgs"
    with connect(url, additional_headers={"Authorization": f"Bearer {server.tokens['vehicle']}"}) as ws:
        while json.loads(ws.recv(timeout=5))["type"] != "resumed":
            pass
        for bad, needle in (
            ("not json", "expected a JSON object"),
            ('{"type": "status", "x_m": "here", "y_m": 0}', "x_m"),
            ('{"type": "status", "x_m": NaN, "y_m": 0}', "finite"),
            ('{"type": "status", "x_m": 1, "y_m": 0, "door": "ajar"}', "door"),
            ('{"type": "teleport"}', "unknown message type 'teleport'"),
            ('{"type": "done"}', "trip_id"),
        ):
            ws.send(bad)
            reply = json.loads(ws.recv(timeout=5))
            assert reply["type"] == "error" and needle in reply["reason"], (bad, reply)
        ws.send('{"type": "ping"}')
        assert json.loads(ws.recv(timeout=5)) == {"type": "pong"}
