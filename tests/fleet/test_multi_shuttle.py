"""Three scripted shuttles (a kinematic stand-in for the simulator, driving the real VehicleClient over
the real WebSocket) serve every ride requested against the real server, following the plan order the
server sends, never carrying more than six seats."""

from __future__ import annotations

import asyncio

import httpx
import numpy as np
import sqlalchemy as sa

from lastmile.fleet.scheduling import CAPACITY_SEATS, LoopRoute
from lastmile.fleet.vehicle_client import VehicleClient
from lastmile.hdmap.service_route import campus_service
from tests.fleet.conftest import ServerProcess, db_engine

N_RIDES = 24
STEP_M = 60.0  # metres the stand-in shuttle moves per 10 ms tick


class ScriptedShuttle:
    """Drives round the loop to the first visit of its plan and reports that visit's trips done."""

    def __init__(self, client: VehicleClient, route: LoopRoute, start_s_m: float) -> None:
        self.client = client
        self.route = route
        self.s_m = start_s_m
        self.onboard = 0
        self.max_onboard = 0
        self.served_here: str | None = None
        self.running = True

    async def status(self, speed_mps: float, behaviour: str, door: str = "closed") -> None:
        x, y, yaw = self.route.polyline.point_at(self.s_m)
        await self.client.send_status(
            x_m=x,
            y_m=y,
            yaw_rad=yaw,
            speed_mps=speed_mps,
            behaviour=behaviour,
            passengers=self.onboard,
            door=door,
        )

    async def run(self) -> None:
        while self.running:
            await asyncio.sleep(0.01)
            if not self.client.plan:
                await self.status(0.0, "idle")
                continue
            stop_id, trip_ids = self.client.plan[0]
            ahead = self.route.ahead_m(self.s_m, self.route.stops[stop_id].route_s_m)
            if ahead > 1e-6 or self.served_here == stop_id:  # drive on (a full lap if just served here)
                self.s_m = (self.s_m + min(ahead if ahead > 1e-6 else STEP_M, STEP_M)) % self.route.length_m
                self.served_here = None
                await self.status(4.0, "cruise")
                continue
            await self.status(0.0, "dwell", door="open")
            trips = [self.client.assignments[t] for t in trip_ids if t in self.client.assignments]
            for trip in sorted(trips, key=lambda a: a.kind != "dropoff"):  # alight before boarding
                self.onboard += {"pickup": trip.seats, "dropoff": -trip.seats}.get(trip.kind, 0)
                self.max_onboard = max(self.max_onboard, self.onboard)
                assert await self.client.complete(trip.id)
            self.served_here = stop_id


def test_three_shuttles_serve_every_ride_within_capacity(durable_server: ServerProcess) -> None:
    server = durable_server
    route = LoopRoute(campus_service())
    rng = np.random.default_rng(6)

    async def scenario() -> list[dict[str, object]]:
        shuttles = []
        with server.client("operator") as op:
            for k in range(3):
                client = VehicleClient(server.url, f"loop-{k}", server.tokens["vehicle"])
                await client.register()
                op.post(
                    f"/api/vehicles/loop-{k}/command", json={"command": "start_service"}
                ).raise_for_status()
                await client.start()
                shuttle = ScriptedShuttle(client, route, route.stops[route.order[k]].route_s_m)
                await shuttle.status(0.0, "idle")
                shuttles.append(shuttle)
        drivers = [asyncio.create_task(s.run()) for s in shuttles]
        headers = {"Authorization": f"Bearer {server.tokens['rider']}"}
        async with httpx.AsyncClient(base_url=server.url, headers=headers, timeout=10) as http:
            ids = []
            for _ in range(N_RIDES):
                o, d = rng.choice(4, size=2, replace=False)
                body = {
                    "origin": route.order[o],
                    "destination": route.order[d],
                    "seats": int(rng.integers(1, 4)),
                }
                res = await http.post("/api/rides", json=body)
                assert res.status_code == 201, res.text
                ids.append(res.json()["id"])
                await asyncio.sleep(float(rng.exponential(0.05)))
            # One ride-log page a poll (a rider token polling 24 rides every 50 ms would be rate limited).
            op_headers = {"Authorization": f"Bearer {server.tokens['operator']}"}
            for _ in range(600):
                log = (await http.get("/api/ride-log?limit=100", headers=op_headers)).json()
                if all(r["state"] == "dropped_off" for r in log["rides"] if r["id"] in ids):
                    break
                await asyncio.sleep(0.05)
            rides = [(await http.get(f"/api/rides/{i}")).json() for i in ids]
        for s in shuttles:
            s.running = False
        await asyncio.gather(*drivers)
        for s in shuttles:
            assert s.max_onboard <= CAPACITY_SEATS
            assert s.onboard == 0
            await s.client.stop()
        assert sum(s.client.stats.assignments_received for s in shuttles) >= 2 * N_RIDES
        return rides

    rides = asyncio.run(scenario())
    assert [r["state"] for r in rides] == ["dropped_off"] * N_RIDES
    assert all(r["picked_up_us"] < r["dropped_off_us"] for r in rides)  # type: ignore[operator]
    engine = db_engine(server)
    with engine.connect() as conn:
        done = conn.execute(
            sa.text("SELECT kind, count(*) FROM trips WHERE state = 'done' GROUP BY kind ORDER BY kind")
        ).all()
        events = conn.execute(sa.text("SELECT count(*) FROM events WHERE kind = 'picked_up'")).scalar_one()
    engine.dispose()
    assert [tuple(r) for r in done] == [("dropoff", N_RIDES), ("pickup", N_RIDES)]
    assert events == N_RIDES
