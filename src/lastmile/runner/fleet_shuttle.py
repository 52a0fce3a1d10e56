"""One shuttle of a fleet run: its simulator, stack, log and server link, and one base tick of it.

``runner.fleet_run`` owns the clock and the server; everything here is per shuttle. The other shuttles
appear in each shuttle's world as road users (``proxy_for`` / ``place_proxy``) at their true poses.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.object_class import ObjectClass
from lastmile.core.sensor_frames import CrossingPresenceFrame, SensorFrame, StopCallFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourState, StackOutput, VehicleStatus
from lastmile.fleet.vehicle_client import VehicleClient
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.recorder.run_log_writer import RunLogWriter
from lastmile.runner.closed_loop import TICK_US, log_hmi_and_ego
from lastmile.runner.fleet_config import FleetConfig
from lastmile.safety.hardware_watchdog import HardwareWatchdog
from lastmile.sim.agents import Agent
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import CrosswalkPedestrians, Scenario
from lastmile.sim.sensors import RCS_DBSM
from lastmile.sim.simulation import Simulation
from lastmile.stack.shuttle_stack import ShuttleStack

PROXY_ID_BASE = 9000  # road-user ids of the other shuttles in each shuttle's world


@dataclass
class FleetShuttle:
    """One shuttle: its simulator, its stack, its log and its link to the server."""

    vid: str
    sim: Simulation
    stack: ShuttleStack
    writer: RunLogWriter
    client: VehicleClient
    proxies: dict[int, Agent] = field(default_factory=dict)
    watchdog: HardwareWatchdog = field(default_factory=HardwareWatchdog)
    stack_alive: bool = True
    status: VehicleStatus | None = None
    last_state: BehaviourState | None = None
    judge_seen: int = 0
    served_stops: list[tuple[float, str]] = field(default_factory=list)
    calls: list[str] = field(default_factory=list)
    onboard: int = 0
    max_onboard: int = 0
    distance_m: float = 0.0
    occupied_s: float = 0.0
    seat_s: float = 0.0
    stack_wall_s: float = 0.0
    hmi: dict[str, str] = field(default_factory=dict)
    frames: list[SensorFrame] = field(default_factory=list)
    presence_seen: dict[str, int] = field(default_factory=dict)
    pedestrian_proxies: list[tuple[Agent, Agent]] = field(default_factory=list)
    anticipating: bool = False


def shuttle_scenario(config: FleetConfig, k: int, seed: int, start_s_m: float) -> Scenario:
    # No stop-button riders: in a fleet run every rider comes through the server. Pedestrians live in
    # shuttle 0's world; the other shuttles' worlds mirror them (one set of pedestrians for all).
    walkers: tuple[CrosswalkPedestrians, ...] = ()
    if k == 0 and config.pedestrian_mean_gap_s is not None:
        walkers = tuple(
            CrosswalkPedestrians(crosswalk=i, mean_gap_s=config.pedestrian_mean_gap_s)
            for i in loop_crosswalks()
        )
    return Scenario(
        name=f"fleet_shuttle_{k}",
        minutes=config.minutes,
        seed=seed,
        start_route_s_m=start_s_m,
        passengers=PassengerConfig(arrivals_per_stop_per_min=0.0),
        cruise_speed_mps=config.cruise_speed_mps,
        crosswalk_pedestrians=walkers,
    )


def loop_crosswalks() -> list[int]:
    """Indices of the map's crosswalks the shuttle loop crosses (their centre within a lane of it)."""
    hdmap = load_campus_map()
    loop = route_polyline(hdmap, campus_shuttle_loop(hdmap), closed=True)
    out = []
    for i, cw in enumerate(hdmap.crosswalks):
        cx, cy = np.asarray(cw.polygon, dtype=float).mean(axis=0)
        if abs(loop.project(float(cx), float(cy)).d_m) < 4.0:
            out.append(i)
    return out


def proxy_for(other: FleetShuttle, k: int) -> Agent:
    """``other`` as a car-sized road user for another shuttle's world (id ``PROXY_ID_BASE + k``)."""
    g = other.sim.world.geometry
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
    place_proxy(agent, other.sim)
    return agent


def place_proxy(agent: Agent, sim: Simulation) -> None:
    """Put the other shuttle where it truly is (footprint centre, heading, speed)."""
    agent.x_m, agent.y_m = sim.world.ego_centre()
    agent.yaw_rad = sim.world.ego.state.yaw_rad
    agent.speed_mps = sim.world.ego.state.speed_mps


def step_shuttle(s: FleetShuttle, tick: int, now: Stamp, t_s: float) -> None:
    """One base tick of one shuttle, in DESIGN.md's phase order (as ``closed_loop`` does)."""
    sim, w = s.sim, s.writer
    sim.advance_world(tick)
    frames: list[SensorFrame] = list(sim.sensor_frames(tick))
    # The plan's stops, as the vehicle's fleet link hands them to the stack.
    frames.extend(StopCallFrame(stamp=now, stop_id=stop, source="dispatch") for stop in s.calls)
    s.calls = []
    frames.extend(s.frames)  # infrastructure reports relayed by the server
    s.frames = []
    out: StackOutput | None = None
    if s.stack_alive:
        t0 = time.perf_counter()
        try:
            out = s.stack.tick(now, frames)
        except Exception as exc:
            s.stack_alive = False
            w.add_event(t_s, "stack_crash", error=f"{type(exc).__name__}: {exc}")
        s.stack_wall_s += time.perf_counter() - t0
    command = out.command if out is not None else None
    brake = s.watchdog.observe(int(now), command)
    if brake is not None:
        command = brake
    sim.apply_command(command)
    sim.referee(out.takeover_request if out is not None else False)
    if out is not None and out.status is not None:
        s.status = out.status
    state = out.decision.state if out is not None and out.decision is not None else None
    if out is not None and state is not None and state != s.last_state:
        w.add_event(
            t_s,
            "state_change",
            **{
                "from": s.last_state.value if s.last_state else "",
                "to": state.value,
                "reason": out.decision.reason if out.decision else "",
            },
        )
        s.last_state = state
    anticipating = out is not None and out.decision is not None and "infrastructure" in out.decision.reason
    if anticipating != s.anticipating:
        w.add_event(t_s, "v2i_anticipation", active=anticipating)
        s.anticipating = anticipating
    for msg in out.hmi if out is not None else ():
        s.hmi[msg.screen] = msg.text
        s.hmi["cue"], s.hmi["light"] = msg.cue, msg.light
        if msg.screen == "front":  # the cue's sound comes with its front message
            s.hmi["sound"] = msg.sound
    log_hmi_and_ego(w, t_s, tick, out, sim, state)
    events = sim.judge.events
    if len(events) > s.judge_seen:
        fresh = events[s.judge_seen :]
        w.add_events(fresh)
        s.judge_seen = len(events)
        for ev_t, kind, data in fresh:
            if kind == "stop_served":
                s.served_stops.append((ev_t, str(data["stop_id"])))


def take_presence(s: FleetShuttle, now: Stamp) -> None:
    """Reports the shuttle's link received since the last look, as frames for its next stack tick."""
    for node, msg in s.client.infrastructure.items():
        captured_us = int(msg["captured_us"])
        if captured_us <= s.presence_seen.get(node, -1):
            continue
        s.presence_seen[node] = captured_us
        s.frames.append(
            CrossingPresenceFrame(
                stamp=Stamp(int(now) + TICK_US),
                node_id=node,
                crosswalk_id=int(msg["crosswalk"]),
                pedestrians_present=bool(msg["present"]),
                captured=Stamp(captured_us),
            )
        )
