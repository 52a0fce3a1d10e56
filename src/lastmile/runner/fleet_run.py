"""``lastmile run --fleet N --serve``: N shuttles in one simulated world, each with its own stack and
vehicle model, each linked to the real dispatch server over its own ``VehicleClient`` WebSocket, and
riders from a Poisson demand model asking for rides over the real HTTP API.

Time. The run is the clock: it advances simulated time as fast as the CPU allows and talks to the
server only at sync points, every ``sync_period_s`` of simulated time. At a sync point it (1) reports
the trips each shuttle finished since the last one (``done``, waiting for the server's ack), (2) sends
each shuttle's status, (3) posts the riders whose request time has come, and (4) ends with a barrier
on every link (a ping answered through the link's ordered queue), so every assignment and plan the
server made in reply has reached the shuttle before simulated time moves on. What a shuttle knows is
then a function of the seed, never of network or CPU timing, and the run never waits on wall-clock
timers; the server's own timestamps (wall clock) are not used for any metric. Wait and ride times
are measured by the run in simulated seconds. The server's timetable clock is off (``--timetable-lead
0``): it would hand out runs by the server's time of day.

The world. Each shuttle has its own closed loop (:mod:`lastmile.runner.loop`: its
:class:`~lastmile.sim.simulation.Simulation`, stack and vehicle safety, logged and black-boxed like a
single run), and the loops are stepped in lockstep; the other shuttles are placed in each world every
tick as road users at their true poses, so shuttles see (radar), avoid and can collide with each
other. Other road users would be drawn separately in each shuttle's world, so the fleet scenario has
none but the mirrored pedestrians (a limitation).

Stops. The shuttle's stack is told the next stop of its plan as ``StopCallFrame(source="dispatch")``
(as the vehicle's fleet link would pass them on); a shuttle without the server (``lastmile run``)
keeps its stop buttons. When the simulator's referee logs a stop served (door closed again at a
stop), the shuttle reports done the trips of its plan's next visit if that visit is at this stop,
drop-offs first (a stop anywhere else is logged as ``fleet_unplanned_stop``).
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from threadpoolctl import threadpool_limits

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import PreparedPolygon
from lastmile.core.object_class import ObjectClass
from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.rng import component_rng
from lastmile.core.run_events import EventKind
from lastmile.core.stamp import Stamp
from lastmile.evaluation.fleet_metrics import (
    RideRecord,
    VehicleRecord,
    compute_fleet_metrics,
    write_fleet_report,
)
from lastmile.fleet.scheduling import CAPACITY_SEATS, fleet_stop_ids
from lastmile.fleet.vehicle_client import Assignment, VehicleClient
from lastmile.recorder.run_log import RunLog
from lastmile.recorder.run_log_writer import RunLogWriter
from lastmile.runner.closed_loop import (
    build_closed_loop,
    evaluate_run,
    load_world_map,
    run_meta,
    sensor_calibration,
)
from lastmile.runner.fleet_config import Demand, FleetConfig, poisson_demand
from lastmile.runner.fleet_server import ServerProcess
from lastmile.runner.fleet_shuttle import (
    FleetLinkCallback,
    FleetShuttle,
    place_proxy,
    proxy_for,
    shuttle_scenario,
    take_presence,
)
from lastmile.runner.loop import run_lockstep
from lastmile.runner.loop_callbacks import (
    BlackBoxCallback,
    RunLogCallback,
    TimingCallback,
    black_box_config,
)
from lastmile.runner.run_config import RunConfig, run_config_dict
from lastmile.sim.agents import Agent
from lastmile.sim.infrastructure import CrossingCamera, CrossingCameraConfig

# N shuttles in one process: the radar object lists keep a fleet hour affordable on one core.
FLEET_RUN_CONFIG = RunConfig().with_perception(PerceptionMode.RADAR_TRACKING)
PEDESTRIAN_PROXY_BASE = 9100  # and of the mirrored pedestrians

ProgressCallback = Callable[[float, float], None]


@dataclass
class _Rider:
    ref: str
    demand: Demand
    requested_s: float
    ride_id: str = ""
    vehicle_id: str = ""
    picked_up_s: float | None = None
    dropped_off_s: float | None = None


@dataclass
class _Camera:
    """A crossing camera node of the fleet world and what it last posted."""

    node_id: str
    crosswalk_id: int
    polygon: PreparedPolygon
    camera: CrossingCamera
    token: str = ""
    last_captured_s: float = -1.0
    last_posted: tuple[float, bool] | None = None
    posts: int = 0
    delivered: int = 0


def run_fleet(
    config: FleetConfig,
    out_dir: Path,
    progress: ProgressCallback | None = None,
    stop: Callable[[], bool] | None = None,
) -> dict[str, Any]:
    """Run the fleet against a fresh server in ``out_dir/server``; writes the run directory and returns
    the fleet metrics (each shuttle's own metrics under ``shuttle-<k>/``).

    ``stop()`` turning true between ticks (Ctrl-C, SIGTERM: :mod:`lastmile.runner.stop_signals`) ends
    the run there; the run directory is written for the time simulated and ``interrupted`` is set.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    server = ServerProcess(out_dir / "server", out_dir / "server" / "runs", route=config.route).start()
    try:
        with threadpool_limits(limits=1):
            return asyncio.run(_run(config, out_dir, server, progress, stop))
    finally:
        server.stop()


async def _run(
    config: FleetConfig,
    out_dir: Path,
    server: ServerProcess,
    progress: ProgressCallback | None,
    stop: Callable[[], bool] | None,
) -> dict[str, Any]:
    seeds = np.random.SeedSequence(config.seed).spawn(config.shuttles + 1)
    run_config = FLEET_RUN_CONFIG.with_cruise_speed(config.cruise_speed_mps)
    shuttles = _build_shuttles(config, run_config, seeds, server, out_dir)
    world_map = load_world_map(shuttles[0].world.scenario.map)
    fleet_ids = fleet_stop_ids(world_map)
    for shuttle in shuttles:
        shuttle.fleet_stop_ids = fleet_ids
    stop_ids = [fleet_ids.get(stop.id, stop.id) for stop in world_map.hdmap.stops]
    window_s = (config.demand_minutes if config.demand_minutes is not None else config.minutes) * 60.0
    demand = poisson_demand(
        stop_ids,
        config.demand_per_pair_per_h,
        min(window_s, config.minutes * 60.0),
        config.max_seats,
        np.random.default_rng(seeds[-1]),
    )
    pedestrians = _mirror_road_users(shuttles)
    route_crosswalks = world_map.layers(step_m=1.0).crosswalks if config.cameras else ()
    cameras = [
        _Camera(
            node_id=f"crossing-cam-{rc.crosswalk.id}",
            crosswalk_id=rc.crosswalk.id,
            polygon=PreparedPolygon(rc.crosswalk.polygon),
            camera=CrossingCamera(
                CrossingCameraConfig(rate_hz=config.camera_rate_hz),
                component_rng(config.seed, f"crossing_camera_{rc.crosswalk.id}"),
            ),
        )
        for rc in route_crosswalks
    ]

    rider_headers = {"Authorization": f"Bearer {server.tokens['rider']}"}
    operator_headers = {"Authorization": f"Bearer {server.tokens['operator']}"}
    riders: list[_Rider] = []
    by_request: dict[str, _Rider] = {}
    wall0, cpu0 = time.perf_counter(), time.process_time()
    tick_us = run_config.loop.tick_us
    async with httpx.AsyncClient(base_url=server.url, timeout=30) as http:
        for s in shuttles:
            await s.client.register(capacity=CAPACITY_SEATS)
            res = await http.post(
                f"/api/vehicles/{s.vid}/command", json={"command": "start_service"}, headers=operator_headers
            )
            _expect(res, 200, f"start_service {s.vid}")
            await s.client.start()
        for cam in cameras:  # each node its own token, as an operator would issue them
            res = await http.post(
                "/api/tokens",
                json={"role": "infrastructure", "subject": cam.node_id},
                headers=operator_headers,
            )
            _expect(res, 201, f"token for {cam.node_id}")
            cam.token = str(res.json()["token"])
        ticks = round(config.minutes * 60.0 * 1e6 / tick_us)
        sync_ticks = round(config.sync_period_s * 1e6 / tick_us)
        dt = tick_us / 1e6
        next_rider = 0
        interrupted = False

        def before_tick(tick: int) -> None:
            """Every shuttle sees the others, and the mirrored pedestrians, where they truly are."""
            for s in shuttles:
                for other in shuttles:
                    if other is not s:
                        place_proxy(s.proxies[id(other)], other.world)
                for a, proxy in s.pedestrian_proxies:
                    proxy.x_m, proxy.y_m, proxy.yaw_rad = a.x_m, a.y_m, a.yaw_rad
                    proxy.speed_mps, proxy.active = a.speed_mps, a.active

        async def after_tick(tick: int) -> bool:
            """Account the tick, relay the cameras, and at sync points talk to the server; True ends."""
            nonlocal next_rider, interrupted
            if stop is not None and stop():
                interrupted = True
                for s in shuttles:
                    s.loop.interrupted = True  # their callbacks keep the black box, as a single run's do
                return True
            now, t_s = Stamp(tick * tick_us), tick * dt
            for s in shuttles:
                s.distance_m += s.world.ego_state.speed_mps * dt
                if s.onboard > 0:
                    s.occupied_s += dt
                    s.seat_s += s.onboard * dt
            if cameras and await _cameras(cameras, pedestrians, t_s, config, http):
                # A report went out: let it reach every shuttle before simulated time moves on.
                for s in shuttles:
                    await s.client.sync()
                    take_presence(s, now)
            if progress is not None and tick % 100 == 0:
                progress(t_s, config.minutes * 60.0)
            if tick % sync_ticks != 0:
                return False
            for s in shuttles:
                await _report_done(s, by_request)
                await _send_status(s)
            while next_rider < len(demand) and demand[next_rider].t_s <= t_s:
                rider = _Rider(
                    ref=f"rider-{config.seed}-{next_rider}", demand=demand[next_rider], requested_s=t_s
                )
                await _request_ride(http, rider, rider_headers)
                by_request[rider.ride_id] = rider
                riders.append(rider)
                next_rider += 1
            for s in shuttles:
                await s.client.sync()
            for s in shuttles:
                # Only the next visit: the stack's mission is a set of stops, and a later visit's
                # stop may lie on a later lap (the server keeps seats within capacity that way).
                s.calls = [s.client.plan[0][0]] if s.client.plan else []
            return (
                config.until_served
                and next_rider == len(demand)
                and t_s >= window_s
                and all(r.dropped_off_s is not None for r in riders)
            )

        end_tick = await run_lockstep([s.loop for s in shuttles], ticks, before_tick, after_tick)
        for s in shuttles:
            await s.client.stop()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    duration_s = end_tick * tick_us / 1e6
    metrics, records = _fleet_metrics(shuttles, riders, cameras, duration_s, wall, cpu, out_dir)
    metrics["interrupted"] = interrupted
    write_fleet_report(metrics, records, out_dir)
    if progress is not None:
        progress(config.minutes * 60.0, config.minutes * 60.0)
    return metrics


def _fleet_metrics(
    shuttles: list[FleetShuttle],
    riders: list[_Rider],
    cameras: list[_Camera],
    duration_s: float,
    wall: float,
    cpu: float,
    out_dir: Path,
) -> tuple[dict[str, Any], list[RideRecord]]:
    """The fleet's metrics, and each shuttle's run directory written under ``out_dir/shuttle-<k>``."""
    records = [
        RideRecord(
            ref=r.ref,
            origin=r.demand.origin,
            destination=r.demand.destination,
            seats=r.demand.seats,
            requested_s=r.requested_s,
            picked_up_s=r.picked_up_s,
            dropped_off_s=r.dropped_off_s,
            vehicle_id=r.vehicle_id,
        )
        for r in riders
    ]
    vehicles = [
        VehicleRecord(
            vehicle_id=s.vid,
            distance_m=s.distance_m,
            duration_s=duration_s,
            occupied_s=s.occupied_s,
            seat_s=s.seat_s,
        )
        for s in shuttles
    ]
    metrics = compute_fleet_metrics(records, vehicles, CAPACITY_SEATS)
    metrics["duration_s"] = duration_s
    for k, s in enumerate(shuttles):
        # Wall and CPU time are the whole fleet's (one process steps every shuttle).
        s.writer.set_timing(
            {
                "wall_s": wall,
                "realtime_factor": duration_s / wall if wall > 0 else None,
                "cpu_s": cpu,
                "stack_wall_s": s.timing.software_s,
                "modules": s.timing.timing.get("modules", {}),
            }
        )
        log: RunLog = s.writer.finish()
        shuttle_metrics = evaluate_run(log, out_dir / f"shuttle-{k}")
        metrics["per_vehicle"][s.vid]["collisions"] = shuttle_metrics.get("collisions_total")
        metrics["per_vehicle"][s.vid]["stops_served"] = shuttle_metrics.get("stops_served")
        metrics["per_vehicle"][s.vid]["max_seats_on_board"] = s.max_onboard
        metrics["per_vehicle"][s.vid]["rule_violations"] = shuttle_metrics.get("rule_violations")
        metrics["per_vehicle"][s.vid]["v2i_anticipations"] = sum(
            1 for e in log.events if e.kind == "v2i_anticipation" and e.data.get("active")
        )
    metrics["infrastructure"] = {
        "cameras": len(cameras),
        "reports_posted": sum(c.posts for c in cameras),
        "reports_delivered": sum(c.delivered for c in cameras),
        "reports_received_by_stacks": {
            s.vid: s.loop.software.report().counters["v2i_reports_received"] for s in shuttles
        },
    }
    timing = {"wall_s": wall, "cpu_s": cpu, "realtime_factor": duration_s / wall if wall > 0 else None}
    metrics["timing"] = timing
    return metrics, records


def _build_shuttles(
    config: FleetConfig,
    run_config: RunConfig,
    seeds: list[np.random.SeedSequence],
    server: ServerProcess,
    out_dir: Path,
) -> list[FleetShuttle]:
    """One closed loop per shuttle, spaced evenly round the loop, logged and black-boxed like a single
    run, with its fleet link in the loop."""
    shuttles: list[FleetShuttle] = []
    loop_length_m: float | None = None
    for k in range(config.shuttles):
        seed_k = int(seeds[k].generate_state(1)[0])
        # Start positions: evenly round the loop (loop length from the first shuttle's simulator).
        start = 0.0 if loop_length_m is None else k * loop_length_m / config.shuttles
        scenario = shuttle_scenario(config, k, seed_k, start)
        loop = build_closed_loop(scenario, run_config)
        loop_length_m = loop.world.service_route.length_m
        meta = dataclasses.replace(
            run_meta(scenario, run_config, loop.world.map_name),
            duration_s=config.minutes * 60.0,
            config={
                "fleet": dataclasses.asdict(config),
                "shuttle": k,
                "start_route_s_m": start,
                "run_config": run_config_dict(run_config),
            },
        )
        vid = f"sim-{k}"
        writer = RunLogWriter(meta)
        shuttle = FleetShuttle(
            vid=vid,
            loop=loop,
            writer=writer,
            client=VehicleClient(server.url, vid, server.tokens["vehicle"]),
            timing=TimingCallback(),
        )
        box = black_box_config(
            out_dir / f"shuttle-{k}" / "recordings",
            run_config.loop.black_box_window_s,
            loop.world,
            sensor_calibration(loop.world, run_config.stack),
            run=(scenario, run_config),
        )
        loop.callbacks.extend(
            [
                RunLogCallback(writer, loop.world, scenario),
                shuttle.timing,
                BlackBoxCallback(box, writer),
                FleetLinkCallback(shuttle),
            ]
        )
        shuttles.append(shuttle)
    return shuttles


def _mirror_road_users(shuttles: list[FleetShuttle]) -> list[Agent]:
    """Every shuttle sees the others; shuttle 0's pedestrians are mirrored into the other worlds.
    Returns those pedestrians."""
    for s in shuttles:
        for other in shuttles:
            if other is not s:
                s.proxies[id(other)] = proxy_for(other, len(s.proxies))
                s.world.add_road_user(s.proxies[id(other)])
    # One set of pedestrians: they walk in shuttle 0's world and are mirrored into the others'.
    pedestrians = [a for a in shuttles[0].world.road_users if a.cls == ObjectClass.PEDESTRIAN]
    for s in shuttles[1:]:
        for j, a in enumerate(pedestrians):
            proxy = Agent(
                id=PEDESTRIAN_PROXY_BASE + j,
                cls=ObjectClass.PEDESTRIAN,
                x_m=a.x_m,
                y_m=a.y_m,
                yaw_rad=a.yaw_rad,
                speed_mps=a.speed_mps,
                length_m=a.length_m,
                width_m=a.width_m,
                rcs_dbsm=a.rcs_dbsm,
                active=a.active,
            )
            s.pedestrian_proxies.append((a, proxy))
            s.world.add_road_user(proxy)
    return pedestrians


async def _send_status(s: FleetShuttle) -> None:
    st = s.status
    if st is None or st.map_from_base is None:
        return
    pose = st.map_from_base
    await s.client.send_status(
        x_m=pose.x_m,
        y_m=pose.y_m,
        yaw_rad=pose.yaw_rad,
        speed_mps=st.speed_mps,
        behaviour=st.state.value,
        health="ok" if st.healthy else "degraded",
        passengers=s.onboard,
        door="open" if st.door_open else "closed",
        hmi=dict(s.hmi) if s.hmi else None,
    )


async def _request_ride(http: httpx.AsyncClient, rider: _Rider, headers: dict[str, str]) -> None:
    d = rider.demand
    body = {"origin": d.origin, "destination": d.destination, "seats": d.seats, "client_ref": rider.ref}
    res = await http.post("/api/rides", json=body, headers=headers)
    _expect(res, 201, f"ride {rider.ref}")
    rider.ride_id = str(res.json()["id"])


def _expect(res: httpx.Response, code: int, what: str) -> None:
    if res.status_code != code:
        raise ConfigError(
            f"dispatch server, {what}: expected HTTP {code}, got {res.status_code} {res.text[:200]}"
        )


async def _report_done(s: FleetShuttle, by_request: dict[str, _Rider]) -> None:
    """For each stop served since the last sync: the plan's next visit is done if it is at that stop
    (drop-offs first). A later visit at the same stop stays for its lap: the server placed it there to
    keep the seats on board within capacity."""
    for ev_t, stop_id in s.served_stops:
        if not s.client.plan or s.client.plan[0][0] != stop_id:
            s.writer.add_event(ev_t, EventKind.FLEET_UNPLANNED_STOP, stop_id=stop_id)
            continue
        visit = s.client.plan[0][1]
        trips: list[Assignment] = [s.client.assignments[t] for t in visit if t in s.client.assignments]
        for trip in sorted(trips, key=lambda a: (a.kind != "dropoff", a.id)):
            await s.client.complete(trip.id)
            rider = by_request.get(trip.request_id or "")
            if trip.kind == "pickup":
                s.onboard += trip.seats
                s.max_onboard = max(s.max_onboard, s.onboard)
                if rider is not None:
                    rider.picked_up_s, rider.vehicle_id = ev_t, s.vid
            elif trip.kind == "dropoff":
                s.onboard -= trip.seats
                if rider is not None:
                    rider.dropped_off_s = ev_t
            s.writer.add_event(
                ev_t,
                EventKind.FLEET_TRIP_DONE,
                trip_id=trip.id,
                trip_kind=trip.kind,
                stop_id=trip.stop_id,
                request_id=trip.request_id or "",
            )
    s.served_stops.clear()


async def _cameras(
    cameras: list[_Camera], pedestrians: list[Agent], t_s: float, config: FleetConfig, http: httpx.AsyncClient
) -> bool:
    """Step every crossing camera; post a received capture when presence changed or the keepalive is
    due. Returns whether anything was posted."""
    posted = False
    for cam in cameras:
        # On the crossing, or stepping onto it within the next second.
        truth = any(
            a.active
            and (
                cam.polygon.contains(a.x_m, a.y_m) or cam.polygon.contains(a.x_m + a.vx_mps, a.y_m + a.vy_mps)
            )
            for a in pedestrians
        )
        cam.camera.step(t_s, truth)
        msg = cam.camera.latest
        if msg is None or msg.captured_s == cam.last_captured_s:
            continue
        cam.last_captured_s = msg.captured_s
        last = cam.last_posted
        if (
            last is not None
            and last[1] == msg.pedestrians_present
            and msg.captured_s - last[0] < config.camera_keepalive_s
        ):
            continue
        body = {
            "node_id": cam.node_id,
            "crosswalk": cam.crosswalk_id,
            "present": msg.pedestrians_present,
            "captured_us": round(msg.captured_s * 1e6),
        }
        res = await http.post(
            "/api/infrastructure/presence", json=body, headers={"Authorization": f"Bearer {cam.token}"}
        )
        _expect(res, 200, f"presence from {cam.node_id}")
        cam.delivered += int(res.json()["delivered_to"])
        cam.posts += 1
        cam.last_posted = (msg.captured_s, msg.pedestrians_present)
        posted = True
    return posted
