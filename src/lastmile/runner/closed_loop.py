"""Runs one scenario in closed loop: simulator and stack joined at the sensor/command boundary."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourState, StackOutput
from lastmile.decision.behaviour_fsm import DecisionConfig
from lastmile.evaluation.metrics import compute_metrics, write_metrics, write_timing
from lastmile.evaluation.report import write_report
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.model import HDMap
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.recorder.run_log import STATE_NAMES, RunLog, RunLogWriter, RunMeta
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation
from lastmile.stack.shuttle_stack import ShuttleStack, StackConfig

TICK_US = 10_000
LOG_EVERY_TICKS = 2  # ego trace at 50 Hz
PERCEPTION_MODE = "radar_tracking"  # the stack perceives through simulated radars; no oracle

ProgressCallback = Callable[[float, float], None]


def run_scenario(scenario: Scenario, progress: ProgressCallback | None = None) -> RunLog:
    """Simulate ``scenario``; returns the run log (wall-clock figures only in ``log.timing``)."""
    with threadpool_limits(limits=1):  # small matrices: BLAS threads only compete with the loop
        return _run(scenario, progress)


def build_closed_loop(scenario: Scenario) -> tuple[HDMap, Simulation, ShuttleStack]:
    """The campus map, the simulator for ``scenario`` and a stack configured for it."""
    hdmap = load_campus_map()
    loop_ids = campus_shuttle_loop(hdmap)
    service_route = route_polyline(hdmap, loop_ids, closed=True)
    geometry = VehicleGeometry()
    sim = Simulation(scenario, hdmap, service_route, geometry, TICK_US)
    # The stack gets the map and its own configuration, never the simulator's objects.
    layers = SLayerDatabase.build(hdmap, loop_ids, step_m=1.0, closed=True)
    decision = DecisionConfig()
    if scenario.cruise_speed_mps is not None:
        decision = dataclasses.replace(decision, cruise_speed_mps=scenario.cruise_speed_mps)
    stack = ShuttleStack(
        layers,
        geometry,
        StackConfig(
            tick_us=TICK_US,
            lateral_controller=scenario.lateral_controller,
            radar_mounts=sim.radar_mounts,
            serve_all_stops=scenario.serve_all_stops,
            decision=decision,
        ),
    )
    return hdmap, sim, stack


def _run(scenario: Scenario, progress: ProgressCallback | None) -> RunLog:
    hdmap, sim, stack = build_closed_loop(scenario)
    duration_s = scenario.minutes * 60.0
    meta = RunMeta(
        seed=scenario.seed,
        weather=scenario.weather,
        perception_mode=PERCEPTION_MODE,
        scenario_name=scenario.name,
        map_name=hdmap.name,
        tick_s=TICK_US / 1e6,
        duration_s=duration_s,
        config=_jsonable(asdict(scenario)),
    )
    writer = RunLogWriter(meta)
    ticks = round(duration_s * 1e6 / TICK_US)
    # Injected faults are ground truth for the evaluation (when each began and ended), never for the stack.
    fault_marks = sorted(
        [(f.start_s, "fault_start", f.kind, f.target) for f in scenario.faults]
        + [(f.end_s, "fault_end", f.kind, f.target) for f in scenario.faults]
    )
    last_state: BehaviourState | None = None
    emitted = 0
    wall_start = time.perf_counter()
    cpu_start = time.process_time()
    stack_wall = 0.0
    stack_alive = True
    for tick in range(ticks):
        now = Stamp(tick * TICK_US)
        t_s = tick * TICK_US / 1e6
        while fault_marks and fault_marks[0][0] <= t_s:
            _, mark, kind, target = fault_marks.pop(0)
            writer.add_event(t_s, mark, kind=kind, target=target)
        sim.advance_world(tick)
        frames = sim.sensor_frames(tick)
        out: StackOutput | None = None
        if stack_alive:
            t0 = time.perf_counter()
            try:
                out = stack.tick(now, frames)
            except Exception as exc:
                # On a vehicle this is a crashed process: the stack is gone for the rest of the run
                # and the vehicle's hardware watchdog brakes (the simulator's answer to no command).
                stack_alive = False
                writer.add_event(t_s, "stack_crash", error=f"{type(exc).__name__}: {exc}")
            stack_wall += time.perf_counter() - t0
        sim.apply_command(out.command if out is not None else None)
        sim.referee(out.takeover_request if out is not None else False)
        state = out.decision.state if out is not None and out.decision is not None else None
        if out is not None and state is not None and state != last_state:
            writer.add_event(
                t_s,
                "state_change",
                **{
                    "from": last_state.value if last_state else "",
                    "to": state.value,
                    "reason": out.decision.reason if out.decision else "",
                },
            )
            if state == BehaviourState.EMERGENCY_STOP and out.decision is not None:
                writer.add_event(t_s, "emergency_stop", reason=out.decision.reason)
            last_state = state
        for msg in out.hmi if out is not None else ():
            writer.add_event(t_s, "hmi", screen=msg.screen, text=msg.text, sound=msg.sound)
        if tick % LOG_EVERY_TICKS == 0:
            s = sim.world.ego.state
            code = STATE_NAMES.index(state.value) if state is not None else -1
            writer.add_ego_row(
                t_s,
                s.x_m,
                s.y_m,
                s.yaw_rad,
                s.speed_mps,
                s.accel_mps2,
                s.steer_front_rad,
                code,
                sim.judge.route_s_m,
            )
        if len(sim.judge.events) > emitted:
            writer.add_events(sim.judge.events[emitted:])
            emitted = len(sim.judge.events)
        if progress is not None and tick % 100 == 0:
            progress(t_s, duration_s)
    wall = time.perf_counter() - wall_start
    cpu = time.process_time() - cpu_start
    timing: dict[str, Any] = {
        "wall_s": wall,
        "realtime_factor": duration_s / wall if wall > 0 else None,
        # CPU seconds of this process: the one-core figure when other work shares the machine.
        "cpu_s": cpu,
        "realtime_factor_cpu": duration_s / cpu if cpu > 0 else None,
        "stack_wall_s": stack_wall,
        "stack_tick_mean_ms": 1e3 * stack_wall / max(ticks, 1),
        "modules": stack.profiler.summary(),
    }
    writer.set_timing(timing)
    if progress is not None:
        progress(duration_s, duration_s)
    return writer.finish()


def evaluate_run(log: RunLog, run_dir: Path) -> dict[str, Any]:
    """Write the run directory: run log, metrics.json, timing.json, report.md with plots."""
    run_dir.mkdir(parents=True, exist_ok=True)
    log.save(run_dir)
    metrics = compute_metrics(log)
    write_metrics(metrics, run_dir)
    write_timing(log.timing, run_dir)
    write_report(log, metrics, run_dir, hdmap=load_campus_map())
    return metrics


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value
