"""Infrastructure nodes (NUS crossing cameras) report pedestrian presence through the real server, which
relays it to every connected vehicle over its WebSocket; roles and bad bodies are refused."""

from __future__ import annotations

import asyncio

from lastmile.fleet.vehicle_client import VehicleClient
from tests.fleet.conftest import ServerProcess


def test_presence_reaches_connected_vehicles_and_only_its_node_may_report(server: ServerProcess) -> None:
    with server.client("operator") as op:
        res = op.post("/api/tokens", json={"role": "infrastructure", "subject": "cam-7"})
        assert res.status_code == 201, res.text
        cam_token = res.json()["token"]

    async def scenario() -> tuple[dict[str, object], int]:
        vehicle = VehicleClient(server.url, "infra-listener", server.tokens["vehicle"])
        await vehicle.register()
        await vehicle.start()
        import httpx

        async with httpx.AsyncClient(base_url=server.url, timeout=10) as http:
            body = {"node_id": "cam-7", "crosswalk": 1, "present": True, "captured_us": 123}
            res = await http.post(
                "/api/infrastructure/presence", json=body, headers={"Authorization": f"Bearer {cam_token}"}
            )
            assert res.status_code == 200, res.text
            delivered = int(res.json()["delivered_to"])
            await vehicle.sync()  # everything queued to the vehicle before the pong has arrived
            got = dict(vehicle.infrastructure["cam-7"])
            # A camera token reports only as its own node; riders and vehicles may not report at all.
            other = {**body, "node_id": "cam-8"}
            auth = {"Authorization": f"Bearer {cam_token}"}
            assert (
                await http.post("/api/infrastructure/presence", json=other, headers=auth)
            ).status_code == 403
            for role in ("rider", "vehicle"):
                h = {"Authorization": f"Bearer {server.tokens[role]}"}
                assert (
                    await http.post("/api/infrastructure/presence", json=body, headers=h)
                ).status_code == 403
            assert (await http.post("/api/infrastructure/presence", json=body)).status_code == 401
            bad = {**body, "crosswalk": -1}
            res = await http.post("/api/infrastructure/presence", json=bad, headers=auth)
            assert res.status_code == 422 and "crosswalk" in res.text
            vehicle_auth = {"Authorization": f"Bearer {server.tokens['vehicle']}"}
            listed = (await http.get("/api/infrastructure", headers=vehicle_auth)).json()
            # (The session's server is shared with the fuzz test, which reports as other nodes too.)
            mine = [p for p in listed if p["node_id"] == "cam-7"]
            assert [(p["crosswalk"], p["present"]) for p in mine] == [(1, True)]
        await vehicle.stop()
        return got, delivered

    got, delivered = asyncio.run(scenario())
    assert delivered >= 1
    assert (got["crosswalk"], got["present"], got["captured_us"]) == (1, True, 123)
