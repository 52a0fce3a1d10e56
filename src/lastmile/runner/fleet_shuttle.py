"""One shuttle of a fleet run: its closed loop, log and server link, and the loop callback of its link.

``runner.fleet_run`` steps every shuttle's loop in lockstep and owns the server; everything here is per
shuttle. The other shuttles appear in each shuttle's world as road users (``proxy_for`` /
``place_proxy``) at their true poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lastmile.core.object_class import ObjectClass
from lastmile.core.run_events import EventKind
from lastmile.core.sensor_frames import CrossingPresenceFrame, SensorFrame, StopCallFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import StopReason, VehicleStatus
from lastmile.fleet.vehicle_client import VehicleClient
from lastmile.hdmap.service_route import ServiceRoute
from lastmile.recorder.run_log_writer import RunLogWriter
from lastmile.runner.closed_loop import load_world_map
from lastmile.runner.fleet_config import FleetConfig
from lastmile.runner.loop import ClosedLoop, LoopCallback, TickRecord
from lastmile.runner.loop_callbacks import TimingCallback
from lastmile.sim.agents import Agent
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import CrosswalkPedestrians, MapSpec, Scenario
from lastmile.sim.sensors import RCS_DBSM
from lastmile.sim.simulation import Simulation

PROXY_ID_BASE = 9000  # road-user ids of the other shuttles in each shuttle's world


@dataclass
class FleetShuttle:
    """One shuttle: its closed loop (world, stack, safety), its log and its link to the server."""

    vid: str
    loop: ClosedLoop[Simulation]
    writer: RunLogWriter
    client: VehicleClient
    timing: TimingCallback
    proxies: dict[int, Agent] = field(default_factory=dict)
    status: VehicleStatus | None = None
    served_stops: list[tuple[float, str]] = field(default_factory=list)
    calls: list[str] = field(default_factory=list)
    onboard: int = 0
    max_onboard: int = 0
    distance_m: float = 0.0
    occupied_s: float = 0.0
    seat_s: float = 0.0
    hmi: dict[str, str] = field(default_factory=dict)
    frames: list[SensorFrame] = field(default_factory=list)
    presence_seen: dict[str, int] = field(default_factory=dict)
    pedestrian_proxies: list[tuple[Agent, Agent]] = field(default_factory=list)
    anticipating: bool = False
    fleet_stop_ids: dict[str, str] = field(default_factory=dict)
    """The dispatch id of each stop by its map id (``fleet.scheduling.fleet_stop_ids``)."""

    def map_stop_id(self, fleet_id: str) -> str:
        """The stack's id of a stop the dispatcher names."""
        return next((m for m, f in self.fleet_stop_ids.items() if f == fleet_id), fleet_id)

    @property
    def world(self) -> Simulation:
        return self.loop.world


class FleetLinkCallback(LoopCallback):
    """The shuttle's fleet link in the loop: hands the plan's next stop and the relayed infrastructure
    reports to the stack with the sensor frames; takes its status, HMI and served stops for the server."""

    def __init__(self, shuttle: FleetShuttle) -> None:
        self.s = shuttle

    def on_sense(self, tick: int, now: Stamp, frames: list[SensorFrame]) -> list[SensorFrame]:
        s = self.s
        # The plan's stops, as the vehicle's fleet link hands them to the stack.
        frames.extend(
            StopCallFrame(stamp=now, stop_id=s.map_stop_id(stop), source="dispatch") for stop in s.calls
        )
        s.calls = []
        frames.extend(s.frames)  # infrastructure reports relayed by the server
        s.frames = []
        return frames

    def on_tick(self, record: TickRecord) -> None:
        s, out = self.s, record.output
        if out is not None and out.status is not None:
            s.status = out.status
        anticipating = out is not None and out.stop_reason is StopReason.INFRASTRUCTURE_CROSSING
        if anticipating != s.anticipating:
            s.writer.add_event(record.t_s, EventKind.V2I_ANTICIPATION, active=anticipating)
            s.anticipating = anticipating
        for msg in out.hmi if out is not None else ():
            s.hmi[msg.screen] = msg.text
            s.hmi["cue"], s.hmi["light"] = msg.cue, msg.light
            if msg.screen == "front":  # the cue's sound comes with its front message
                s.hmi["sound"] = msg.sound
        for ev_t, kind, data in record.events:
            if kind == "stop_served":
                map_id = str(data["stop_id"])
                s.served_stops.append((ev_t, s.fleet_stop_ids.get(map_id, map_id)))


def shuttle_scenario(config: FleetConfig, k: int, seed: int, start_s_m: float) -> Scenario:
    # No stop-button riders: in a fleet run every rider comes through the server. Pedestrians live in
    # shuttle 0's world; the other shuttles' worlds mirror them (one set of pedestrians for all).
    map_spec = MapSpec(name="route", route=config.route) if config.route else MapSpec()
    walkers: tuple[CrosswalkPedestrians, ...] = ()
    if k == 0 and config.pedestrian_mean_gap_s is not None:
        walkers = tuple(
            CrosswalkPedestrians(crosswalk=i, mean_gap_s=config.pedestrian_mean_gap_s)
            for i in loop_crosswalks(load_world_map(map_spec))
        )
    return Scenario(
        name=f"fleet_shuttle_{k}",
        map=map_spec,
        minutes=config.minutes,
        seed=seed,
        start_route_s_m=start_s_m,
        passengers=PassengerConfig(arrivals_per_stop_per_min=0.0),
        crosswalk_pedestrians=walkers,
    )


def loop_crosswalks(service: ServiceRoute) -> list[int]:
    """Indices of the map's crosswalks the service loop crosses (their centre within a lane of it)."""
    out = []
    for i, cw in enumerate(service.hdmap.crosswalks):
        cx, cy = np.asarray(cw.polygon, dtype=float).mean(axis=0)
        if abs(service.polyline.project(float(cx), float(cy)).d_m) < 4.0:
            out.append(i)
    return out


def proxy_for(other: FleetShuttle, k: int) -> Agent:
    """``other`` as a car-sized road user for another shuttle's world (id ``PROXY_ID_BASE + k``)."""
    g = VehicleGeometry()
    agent = Agent(
        id=PROXY_ID_BASE + k,
        cls=ObjectClass.CAR,
        x_m=0.0,
        y_m=0.0,
        yaw_rad=0.0,
        speed_mps=0.0,
        length_m=g.length_m,
        width_m=g.width_m,
        rcs_dbsm=RCS_DBSM[ObjectClass.CAR],
    )
    place_proxy(agent, other.world)
    return agent


def place_proxy(agent: Agent, world: Simulation) -> None:
    """Put the other shuttle where it truly is (footprint centre, heading, speed)."""
    agent.x_m, agent.y_m = world.ego_centre()
    agent.yaw_rad = world.ego_state.yaw_rad
    agent.speed_mps = world.ego_state.speed_mps


def take_presence(s: FleetShuttle, now: Stamp) -> None:
    """Reports the shuttle's link received since the last look, as frames for its next stack tick."""
    for node, msg in s.client.infrastructure.items():
        captured_us = int(msg["captured_us"])
        if captured_us <= s.presence_seen.get(node, -1):
            continue
        s.presence_seen[node] = captured_us
        s.frames.append(
            CrossingPresenceFrame(
                stamp=Stamp(int(now) + s.loop.tick_us),
                node_id=node,
                crosswalk_id=int(msg["crosswalk"]),
                pedestrians_present=bool(msg["present"]),
                captured=Stamp(captured_us),
            )
        )
