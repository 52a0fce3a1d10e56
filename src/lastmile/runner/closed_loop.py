"""Runs one scenario in closed loop: simulator and stack joined at the sensor/command boundary."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from lastmile.core.errors import ConfigError
from lastmile.core.safety_messages import FailSafeLevel
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourState, StackOutput
from lastmile.decision.decision_config import DecisionConfig
from lastmile.evaluation.metrics import compute_metrics, write_metrics, write_timing
from lastmile.evaluation.report import write_report
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.model import HDMap
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.recorder.black_box import BlackBox, BlackBoxConfig
from lastmile.recorder.run_log import STATE_NAMES, RunLog, RunMeta
from lastmile.recorder.run_log_writer import RunLogWriter
from lastmile.runner.operator_estop import EStopAction, OperatorEStop
from lastmile.safety.hardware_watchdog import HardwareWatchdog
from lastmile.safety.reliability_config import ReliabilityConfig, raw_sensor_specs
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation
from lastmile.stack.shuttle_stack import DEFAULT_SENSORS, PERCEPTION_MODES, ShuttleStack, StackConfig

TICK_US = 10_000
LOG_EVERY_TICKS = 2  # ego trace at 50 Hz
DEFAULT_PERCEPTION_MODE = "lidar_camera_radar"
"""Raw LiDAR sweeps, camera boxes and radar objects through the stack's own perception; no oracle.
"radar_tracking" (radar object lists only) is the cheaper mode the safety sweeps and fleet runs use."""

ProgressCallback = Callable[[float, float], None]


def run_scenario(
    scenario: Scenario,
    progress: ProgressCallback | None = None,
    black_box_dir: Path | None = None,
    perception_mode: str = DEFAULT_PERCEPTION_MODE,
) -> RunLog:
    """Simulate ``scenario``; returns the run log (wall-clock figures only in ``log.timing``).

    With ``black_box_dir``, the stack's black box keeps the last 30 s and writes it there as MCAP on a
    takeover, an emergency stop, a collision or a crash of the stack (``recording`` events say where).
    """
    with threadpool_limits(limits=1):  # small matrices: BLAS threads only compete with the loop
        return _run(scenario, progress, black_box_dir, perception_mode)


def build_closed_loop(
    scenario: Scenario, perception_mode: str = DEFAULT_PERCEPTION_MODE
) -> tuple[HDMap, Simulation, ShuttleStack]:
    """The campus map, the simulator for ``scenario`` and a stack configured for it.

    ``perception_mode`` is one of :data:`lastmile.stack.shuttle_stack.PERCEPTION_MODES`; the raw mode
    makes the simulator cast LiDAR sweeps and run its camera detectors.
    """
    if perception_mode not in PERCEPTION_MODES:
        raise ConfigError(f"perception mode: expected one of {PERCEPTION_MODES}, got {perception_mode!r}")
    hdmap = load_campus_map()
    loop_ids = campus_shuttle_loop(hdmap)
    service_route = route_polyline(hdmap, loop_ids, closed=True)
    geometry = VehicleGeometry()
    raw = perception_mode == "lidar_camera_radar"
    sim = Simulation(scenario, hdmap, service_route, geometry, TICK_US, raw_sensors=raw)
    rig = sim.raw_sensors
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
            light_cameras=sim.light_cameras.cameras,
            serve_all_stops=scenario.serve_all_stops,
            decision=decision,
            perception_mode=perception_mode,
            # The sensors' calibration, as a real vehicle's stack is configured with it.
            lidar_mounts={s.sensor_id: s.base_from_sensor for s in rig.lidar_specs} if rig else {},
            cameras=tuple(c.camera for c in rig.cameras) if rig else (),
            reliability=ReliabilityConfig(
                sensors=DEFAULT_SENSORS
                + (
                    raw_sensor_specs(
                        tuple(s.sensor_id for s in rig.lidar_specs), tuple(c.camera_id for c in rig.cameras)
                    )
                    if rig
                    else ()
                )
            ),
        ),
        # Module faults of the scenario reach the stack through its fault-injection port.
        fault_hook=lambda module, now_us: sim.faults.module_fault(module, now_us / 1e6),
    )
    return hdmap, sim, stack


def _run(
    scenario: Scenario, progress: ProgressCallback | None, black_box_dir: Path | None, perception_mode: str
) -> RunLog:
    hdmap, sim, stack = build_closed_loop(scenario, perception_mode)
    duration_s = scenario.minutes * 60.0
    meta = RunMeta(
        seed=scenario.seed,
        weather=scenario.weather,
        perception_mode=perception_mode,
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
    # The vehicle's independent hardware trigger: full brake if the stack's command stream stops.
    watchdog = HardwareWatchdog()
    watchdog_tripped = False
    box = (
        BlackBox(BlackBoxConfig(out_dir=black_box_dir, sensor_mounts=sim.radar_mounts))
        if black_box_dir is not None
        else None
    )
    last_level = FailSafeLevel.NONE
    operator_had_control = False
    estop = OperatorEStop(scenario.estop_in_state, scenario.estop_release_s, scenario.estop_min_speed_mps)
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
                # and the vehicle's hardware watchdog brakes.
                stack_alive = False
                error = f"{type(exc).__name__}: {exc}"
                writer.add_event(t_s, "stack_crash", error=error)
                if box is not None:
                    box.dump("crash", reason=error, now_us=int(now))
            stack_wall += time.perf_counter() - t0
        command = out.command if out is not None else None
        brake = watchdog.observe(int(now), command)
        if brake is not None:
            if not watchdog_tripped:
                writer.add_event(t_s, "hardware_watchdog", reason="no fresh command for 100 ms")
                watchdog_tripped = True
            command = brake
        sim.apply_command(command)
        sim.referee(out.takeover_request if out is not None else False)
        directive = out.safety if out is not None else None
        if directive is not None and directive.level != last_level:
            writer.add_event(
                t_s,
                "safety",
                level=directive.level.name,
                mrm=directive.mrm.name,
                reason="; ".join(directive.reasons),
            )
            last_level = directive.level
        # The safety driver handing back is the operator's reset of a latched emergency stop.
        if operator_had_control and not sim.operator.in_control and stack_alive:
            stack.safety.operator_reset(int(now))
        operator_had_control = sim.operator.in_control
        if box is not None:
            box.record_frames(int(now), frames)
            if out is not None:
                box.record_output(int(now), out)
                if directive is not None and directive.level != FailSafeLevel.NONE:
                    box.record(int(now), "/safety/directive", directive)
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
                _trigger(box, "emergency_stop", now, out.decision.reason)
            last_state = state
        action = estop.step(t_s, state, sim.world.ego.state.speed_mps) if stack_alive else None
        if action == EStopAction.PRESS:
            stack.safety.operator_emergency_stop(int(now), f"operator e-stop in {scenario.estop_in_state}")
            writer.add_event(t_s, "operator_estop", state=scenario.estop_in_state)
        elif action == EStopAction.RELEASE:
            stack.safety.operator_reset(int(now))
            writer.add_event(t_s, "operator_release", state=scenario.estop_in_state)
        log_hmi_and_ego(writer, t_s, tick, out, sim, state)
        if len(sim.judge.events) > emitted:
            fresh = sim.judge.events[emitted:]
            writer.add_events(fresh)
            emitted = len(sim.judge.events)
            for _, event_kind, data in fresh:
                if event_kind in ("takeover", "collision"):
                    _trigger(box, event_kind, now, str(data))
        if progress is not None and tick % 100 == 0:
            progress(t_s, duration_s)
    if box is not None:
        box.close()
        for path in sorted(box.dumps):
            # blackbox_<trigger>_<t>s_<n>.mcap; the trigger may itself hold underscores (emergency_stop).
            head, t_text, _ = path.stem.rsplit("_", 2)
            trigger = head.removeprefix("blackbox_")
            writer.add_event(float(t_text.rstrip("s")), "recording", path=str(path), trigger=trigger)
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
    if stack.raw is not None:
        st = stack.raw.stats
        offsets = st.curb_offsets_m
        timing["raw_perception"] = {
            "rig_frames": st.rig_frames,
            "incomplete_frames": st.incomplete_frames,
            "skipped_no_pose": st.skipped_no_pose,
            "clusters_per_frame": st.clusters / max(st.rig_frames, 1),
            "curb_valid_frames": st.curb_valid,
            "curb_offset_median_m": float(np.median(offsets)) if offsets else None,
        }
    writer.set_timing(timing)
    if progress is not None:
        progress(duration_s, duration_s)
    return writer.finish()


def log_hmi_and_ego(
    writer: RunLogWriter,
    t_s: float,
    tick: int,
    out: StackOutput | None,
    sim: Simulation,
    state: BehaviourState | None,
) -> None:
    """The tick's HMI messages as events, and every LOG_EVERY_TICKS the ego row (one shuttle's log)."""
    for msg in out.hmi if out is not None else ():
        writer.add_event(
            t_s, "hmi", screen=msg.screen, text=msg.text, sound=msg.sound, light=msg.light, cue=msg.cue
        )
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


def _trigger(box: BlackBox | None, kind: str, now: Stamp, reason: str) -> None:
    """Ask the black box to write its window, in the background (repeats within 5 s join one file)."""
    if box is not None:
        box.trigger(kind, int(now), reason)


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
