"""Against the real server process: what an abusive or careless client sends is refused early, in one
clear line, without a 5xx, without echoing the body, and without holding up other clients."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Iterator

import httpx
import pytest

from tests.fleet.conftest import ServerProcess

BIG_BYTES = 20_000_000


def _big_body() -> bytes:
    """20 MB of JSON: a ride request with a 10-million-element extra field (on main: parsed and
    validated on the event loop, then echoed back whole in the 422)."""
    junk = b"0," * (BIG_BYTES // 2 - 1) + b"0"
    return b'{"origin": "S1", "destination": "S2", "junk": [' + junk + b"]}"


def test_a_20_mb_body_is_refused_with_413_from_its_content_length(server: ServerProcess) -> None:
    with server.client("rider") as rider:
        res = rider.post("/api/rides", content=_big_body(), headers={"Content-Type": "application/json"})
    assert res.status_code == 413
    assert "expected at most 65536 bytes" in res.json()["detail"]
    assert len(res.content) < 500  # nothing of the body comes back


def test_a_chunked_20_mb_body_is_refused_while_it_streams(server: ServerProcess) -> None:
    body = _big_body()
    sent = 0

    def chunks() -> Iterator[bytes]:
        nonlocal sent
        for k in range(0, len(body), 65_536):
            sent += 65_536
            yield body[k : k + 65_536]

    with server.client("rider") as rider:
        try:
            res = rider.post("/api/rides", content=chunks(), headers={"Content-Type": "application/json"})
        except (httpx.WriteError, httpx.RemoteProtocolError, httpx.ReadError):
            # The server answered 413 and closed the connection under a client still sending: it
            # stopped reading early (on main it read all 20 MB and answered after seconds, or timed out).
            assert sent < len(body)
        else:
            assert res.status_code == 413 and "got more than that" in res.json()["detail"]
            assert len(res.content) < 500
        assert rider.get("/api/stops").status_code == 200


def test_other_clients_are_answered_while_a_large_body_arrives(server: ServerProcess) -> None:
    """On main a 20 MB body held the event loop for ~20 s and every ``GET /api/stops`` waited for it."""

    async def scenario() -> tuple[int | None, float]:
        headers = {"Authorization": f"Bearer {server.tokens['rider']}", "Content-Type": "application/json"}
        async with httpx.AsyncClient(base_url=server.url, headers=headers, timeout=60) as http:
            big = asyncio.create_task(http.post("/api/rides", content=_big_body()))
            worst_s = 0.0
            # Poll while the big request is in flight (at most 30 s): the slowest answer is the stall.
            for _ in range(300):
                t0 = time.perf_counter()
                assert (await http.get("/api/stops")).status_code == 200
                worst_s = max(worst_s, time.perf_counter() - t0)
                if big.done():
                    break
                await asyncio.sleep(0.1)
            try:
                status = (await big).status_code
            except httpx.TransportError:
                status = None
            return status, worst_s

    status, worst_s = asyncio.run(scenario())
    assert status in (413, None)
    # Not a timing target: on main the slowest waited many seconds; anything near that means the loop
    # was held by the body.
    assert worst_s < 2.0


@pytest.mark.parametrize(
    ("raw", "needle"),
    [
        (b'{"origin": "S1", "destination": "S2", "seats": 1e309}', "1e309"),
        (b'{"origin": "S1", "destination": "S2", "seats": NaN}', "NaN"),
        (b'{"origin": "S1", "destination": "S2", "seats": -Infinity}', "-Infinity"),
        (b'{"origin": "S1", "destination": "S2", "seats": ' + b"9" * 5000 + b"}", "at most 19 digits"),
    ],
)
def test_non_finite_or_huge_json_numbers_are_one_clear_422(
    server: ServerProcess, raw: bytes, needle: str
) -> None:
    with server.client("rider") as rider:
        res = rider.post("/api/rides", content=raw, headers={"Content-Type": "application/json"})
        assert res.status_code == 422
        detail = res.json()["detail"]
        assert isinstance(detail, str) and needle in detail and "\n" not in detail
        assert rider.get("/api/stops").status_code == 200  # the connection and the server are fine
    assert "Traceback" not in server.log_text()


def test_nan_without_a_content_type_is_refused_too(server: ServerProcess) -> None:
    with server.client("rider") as rider:
        res = rider.post("/api/rides", content=b'{"origin": "S1", "destination": "S2", "seats": NaN}')
    assert res.status_code == 422 and "NaN" in res.json()["detail"]


def test_a_long_ride_id_is_not_echoed_in_the_404(server: ServerProcess) -> None:
    with server.client("rider") as rider:
        res = rider.get("/api/rides/" + "z" * 5000)
    assert res.status_code == 422 and "zzzz" not in res.text


def test_a_validation_error_does_not_echo_the_input(server: ServerProcess) -> None:
    secret = "s3cr3t-" + "y" * 40_000
    with server.client("rider") as rider:
        res = rider.post("/api/rides", json={"origin": secret, "destination": "S2"})
    assert res.status_code == 422
    assert "s3cr3t" not in res.text and len(res.content) < 2000
    assert res.json()["detail"][0]["loc"] == ["body", "origin"]


def test_a_rider_flooding_the_server_gets_429_and_other_riders_do_not(server: ServerProcess) -> None:
    with server.client("operator") as op:
        flooder = op.post("/api/tokens", json={"role": "rider", "subject": "flooder"}).json()["token"]
        calm = op.post("/api/tokens", json={"role": "rider", "subject": "calm"}).json()["token"]
    with httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {flooder}"}) as flood:
        codes = [flood.get("/api/whoami") for _ in range(150)]
    refused = [r for r in codes if r.status_code == 429]
    assert refused, "150 back-to-back requests from one rider token were never limited"
    assert {r.status_code for r in codes} == {200, 429}
    assert int(refused[0].headers["Retry-After"]) >= 1
    assert "requests/s per rider token" in refused[0].json()["detail"]
    with httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {calm}"}) as other:
        assert other.get("/api/whoami").json() == {"role": "rider", "subject": "calm"}


def test_idempotency_keys_belong_to_each_rider_and_a_changed_payload_is_409(server: ServerProcess) -> None:
    with server.client("operator") as op:
        alice = op.post("/api/tokens", json={"role": "rider", "subject": "alice"}).json()["token"]
        bob = op.post("/api/tokens", json={"role": "rider", "subject": "bob-2"}).json()["token"]
    body = {"origin": "S1", "destination": "S3", "client_ref": "shared-key-1"}
    with (
        httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {alice}"}) as a,
        httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {bob}"}) as b,
    ):
        first = a.post("/api/rides", json=body)
        other = b.post("/api/rides", json=body)  # main: 403 "belongs to another rider"
        assert first.status_code == 201 and other.status_code == 201
        assert first.json()["id"] != other.json()["id"]
        assert a.post("/api/rides", json=body).json()["id"] == first.json()["id"]
        changed = a.post("/api/rides", json=body | {"destination": "S4"})  # main: 200 with the old ride
        assert changed.status_code == 409
        assert "S1->S3" in changed.json()["detail"] and "S1->S4" in changed.json()["detail"]
        assert a.post("/api/rides", json=body | {"seats": 2}).status_code == 409


def test_the_ride_log_pages_and_filters_every_ride(server: ServerProcess) -> None:
    with server.client("operator") as op:
        tok = op.post("/api/tokens", json={"role": "rider", "subject": "pager"}).json()["token"]
        with httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {tok}"}) as rider:
            made = [
                rider.post("/api/rides", json={"origin": "S4", "destination": "S2"}).json() for _ in range(7)
            ]
            rider.delete(f"/api/rides/{made[0]['id']}").raise_for_status()
        page = op.get("/api/ride-log", params={"stop": "S4", "limit": 3}).json()
        assert page["total"] >= 7 and len(page["rides"]) == 3
        ids = [r["id"] for r in page["rides"]]
        later = op.get("/api/ride-log", params={"stop": "S4", "limit": 3, "offset": 3}).json()
        assert not set(ids) & {r["id"] for r in later["rides"]}
        assert ids[0] == made[-1]["id"]  # newest first
        cancelled = op.get("/api/ride-log", params={"state": "cancelled", "limit": 500}).json()
        assert made[0]["id"] in {r["id"] for r in cancelled["rides"]}
        assert all(r["state"] == "cancelled" for r in cancelled["rides"])
        with server.client("rider") as rider:
            assert rider.get("/api/ride-log").status_code == 403


# ------------------------------------------------------------------- the guard alone (timing-free)
async def _echo(scope: dict[str, object], receive: object, send: object) -> None:
    raise AssertionError("the app must not be reached")


def test_a_body_that_trickles_in_is_refused_with_408() -> None:
    from lastmile.fleet.request_guard import RequestGuard

    guard = RequestGuard(_echo, max_body_bytes=1000, body_timeout_s=0.2)  # type: ignore[arg-type]
    sent: list[dict[str, object]] = []

    async def receive() -> dict[str, object]:
        await asyncio.sleep(0.05)  # one byte every 50 ms: a slowloris body
        return {"type": "http.request", "body": b"{", "more_body": True}

    async def send(message: dict[str, object]) -> None:
        sent.append(message)

    scope = {"type": "http", "method": "POST", "headers": [(b"content-type", b"application/json")]}
    asyncio.run(guard(scope, receive, send))  # type: ignore[arg-type]
    assert sent[0]["status"] == 408
    assert b"expected it complete within 0.2 s" in sent[1]["body"]  # type: ignore[operator]


def test_a_token_bucket_refills_at_its_rate_and_names_the_wait() -> None:
    from fastapi import HTTPException

    from lastmile.fleet.auth import Principal
    from lastmile.fleet.rate_limit import RateLimit, TokenBuckets

    buckets = TokenBuckets({"rider": RateLimit(rate_per_s=2.0, burst=3)})
    alice, bob = Principal("rider", "alice", "sha-a"), Principal("rider", "bob", "sha-b")
    for _ in range(3):
        buckets.check(alice, now_s=0.0)
    with pytest.raises(HTTPException) as refused:
        buckets.check(alice, now_s=0.1)
    assert refused.value.status_code == 429
    assert refused.value.headers == {"Retry-After": "1"}  # 0.4 s to the next request, rounded up
    buckets.check(bob, now_s=0.1)  # another token has its own bucket
    buckets.check(alice, now_s=0.6)  # 0.6 s at 2/s refilled one request
    with pytest.raises(HTTPException):
        buckets.check(alice, now_s=0.6)
    assert buckets.refused == 2
    TokenBuckets({"rider": RateLimit(rate_per_s=0.0, burst=0)}).check(alice)  # 0: no limit


def test_a_vehicle_websocket_message_over_64_kib_closes_the_link(server: ServerProcess) -> None:
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    with server.client("operator") as op:
        assert op.post("/api/vehicles", json={"id": "big-msgs"}).status_code in (200, 201)
    url = server.url.replace("http", "ws") + "/ws/vehicle/big-msgs"
    with connect(url, additional_headers={"Authorization": f"Bearer {server.tokens['vehicle']}"}) as ws:
        while json.loads(ws.recv(timeout=5))["type"] != "resumed":
            pass
        ws.send(json.dumps({"type": "status", "x_m": 1.0, "y_m": 0.0, "behaviour": "x" * 100_000}))
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=5)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009  # message too big


def test_a_token_sending_bad_bodies_is_rate_limited_before_they_are_read(server: ServerProcess) -> None:
    with server.client("operator") as op:
        tok = op.post("/api/tokens", json={"role": "rider", "subject": "nan-flood"}).json()["token"]
    headers = {"Authorization": f"Bearer {tok}", "Content-Type": "application/json"}
    with httpx.Client(base_url=server.url, headers=headers) as http:
        codes = {http.post("/api/rides", content=b'{"seats": NaN}').status_code for _ in range(150)}
    assert codes == {422, 429}
