"""The loop's recording and reporting phase: run log, black box, progress and timing, as callbacks.

Every kind of run (single, fleet, sweep, tests, benchmarks) composes the same callbacks, so a fleet's
shuttle logs its watchdog trips, safety levels and black-box recordings exactly as a single run does.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.polyline import Polyline
from lastmile.core.run_events import EventKind
from lastmile.core.safety_messages import FailSafeLevel
from lastmile.core.sensor_frames import GnssInsFrame, SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourState, LocalizationEstimate
from lastmile.hdmap.model import HDMap
from lastmile.recorder.black_box import BlackBox, BlackBoxConfig
from lastmile.recorder.foxglove_views import planar_matrix
from lastmile.recorder.live_view import LiveView, LiveViewConfig
from lastmile.recorder.run_localization import INVALID_SOURCE, POSITION_SOURCES
from lastmile.recorder.run_log import STATE_NAMES
from lastmile.recorder.run_log_writer import RunLogWriter
from lastmile.runner.loop import ClosedLoop, LoopCallback, TickRecord
from lastmile.runner.run_config import RunConfig, run_config_to_toml
from lastmile.sim.scenario import Scenario, scenario_to_toml
from lastmile.sim.simulation import Simulation
from lastmile.stack.vehicle_build import SensorCalibration

LOG_EVERY_TICKS = 2  # ego trace at 50 Hz with the 10 ms tick
AGENTS_EVERY_TICKS = 50
"""Other road users at 2 Hz: enough to draw their tracks and place them at an encounter (a pedestrian
moves 0.7 m between samples), a few kB a minute."""
PROGRESS_EVERY_TICKS = 100
BLACK_BOX_TRIGGERS = ("takeover", "collision")
"""Referee events that make the black box write its window (besides e-stops and crashes)."""

ProgressFn = Callable[[float, float], None]

NO_GNSS_YET, NO_FIX, INVALID_POSE = "none_yet", "no_fix", "invalid"
"""Values of ``localization`` events besides the GNSS qualities and position sources."""


class RunLogCallback(LoopCallback):
    """Writes the run log: injected faults, crashes, watchdog trips, safety levels, behaviour states,
    HMI messages, the referee's events and the ego trace (every :data:`LOG_EVERY_TICKS` ticks)."""

    def __init__(self, writer: RunLogWriter, world: Simulation, scenario: Scenario) -> None:
        self.writer = writer
        self.world = world
        # Injected faults are ground truth for the evaluation (when each began and ended), never for the
        # vehicle.
        self._fault_marks = sorted(
            [(f.start_s, EventKind.FAULT_START, f.kind, f.target) for f in scenario.faults]
            + [(f.end_s, EventKind.FAULT_END, f.kind, f.target) for f in scenario.faults]
        )
        self._failing = False
        self._watchdog_logged = False
        self._level = FailSafeLevel.NONE
        self._state: BehaviourState | None = None
        self._gnss = NO_GNSS_YET
        self._localized: tuple[str, str] | None = None
        self._road_users_seen: set[int] = set()
        self._route_hint_s: float | None = None
        self._path: Polyline | None = None
        self._true_pose = (math.nan, math.nan, math.nan)

    def on_sense(self, tick: int, now: Stamp, frames: list[SensorFrame]) -> list[SensorFrame]:
        # The true pose at ``now``, before the command moves the vehicle (the estimate's instant).
        s = self.world.ego_state
        self._true_pose = (s.x_m, s.y_m, s.yaw_rad)
        return frames

    def on_tick(self, record: TickRecord) -> None:
        w, t_s = self.writer, record.t_s
        while self._fault_marks and self._fault_marks[0][0] <= t_s:
            _, mark, kind, target = self._fault_marks.pop(0)
            w.add_event(t_s, mark, kind=kind, target=target)
        if record.failure and not self._failing:
            w.add_event(t_s, EventKind.STACK_CRASH, error=record.failure)
        self._failing = bool(record.failure)
        if record.verdict.watchdog_tripped and not self._watchdog_logged:
            w.add_event(t_s, EventKind.HARDWARE_WATCHDOG, reason="no fresh command for 100 ms")
            self._watchdog_logged = True
        self._safety_level(record)
        self._localization(record)
        self._localization_row(record)
        self._state_change(record)
        for msg in record.output.hmi if record.output is not None else ():
            w.add_event(
                t_s,
                EventKind.HMI,
                screen=msg.screen,
                text=msg.text,
                sound=msg.sound,
                light=msg.light,
                cue=msg.cue,
            )
        if record.tick % LOG_EVERY_TICKS == 0:
            s = self.world.ego_state
            code = STATE_NAMES.index(record.state.value) if record.state is not None else -1
            w.add_ego_row(
                t_s,
                s.x_m,
                s.y_m,
                s.yaw_rad,
                s.speed_mps,
                s.accel_mps2,
                s.steer_front_rad,
                code,
                self.world.route_progress_m,
            )
        if record.tick % AGENTS_EVERY_TICKS == 0:
            self._road_users(t_s)
        if record.events:
            w.add_events(record.events)

    def _road_users(self, t_s: float) -> None:
        """The active road users' positions (ground truth, for the report only); each one's class once."""
        users = [a for a in self.world.road_users if a.active]
        for a in users:
            if a.id not in self._road_users_seen:
                self._road_users_seen.add(a.id)
                self.writer.add_event(t_s, EventKind.ROAD_USER, agent_id=a.id, agent_class=a.cls.name.lower())
        if users:
            self.writer.add_agent_rows(t_s, [a.id for a in users], [(a.x_m, a.y_m) for a in users])

    def _safety_level(self, record: TickRecord) -> None:
        directive = record.verdict.directive
        if directive.level != self._level:
            self.writer.add_event(
                record.t_s,
                EventKind.SAFETY,
                level=directive.level.name,
                mrm=directive.mrm.name,
                reason="; ".join(directive.reasons),
            )
            self._level = directive.level

    def _localization(self, record: TickRecord) -> None:
        """A ``localization`` event whenever the pose's source or the GNSS fix the vehicle received
        changes (as the vehicle sees them: its estimate and its receiver's frames)."""
        for frame in record.frames:
            if isinstance(frame, GnssInsFrame):
                self._gnss = frame.quality.value if frame.fix_ok else NO_FIX
        diagnostics = record.output.diagnostics if record.output is not None else None
        est = diagnostics.estimate if diagnostics is not None else None
        if est is None:
            return
        now = (est.source.value if est.valid else INVALID_POSE, self._gnss)
        if now != self._localized:
            self.writer.add_event(
                record.t_s, EventKind.LOCALIZATION, source=now[0], gnss=now[1], pos_std_m=est.pos_std_m
            )
            self._localized = now

    def _localization_row(self, record: TickRecord) -> None:
        """On ticks that carry the stack's estimate (planning cycles): the estimate as the stack
        reported it, and the true rear axle's lateral offsets from the route and the latest plan."""
        out = record.output
        if out is None:
            return
        if out.trajectory is not None and len(out.trajectory.points) >= 2:
            self._path = Polyline(out.trajectory.points[:, :2])
        est = out.diagnostics.estimate if out.diagnostics is not None else None
        if est is None:
            return
        x, y, yaw = self._true_pose
        f = self.world.service_route.project(x, y, hint_s_m=self._route_hint_s, window_m=20.0)
        self._route_hint_s = f.s_m
        path_d = self._path.project(x, y).d_m if self._path is not None else math.nan
        self.writer.add_localization_row(record.t_s, *_estimate_columns(est), x, y, yaw, f.d_m, path_d)

    def _state_change(self, record: TickRecord) -> None:
        state, out = record.state, record.output
        if out is None or out.decision is None or state is None or state == self._state:
            return
        self.writer.add_event(
            record.t_s,
            EventKind.STATE_CHANGE,
            **{
                "from": self._state.value if self._state else "",
                "to": state.value,
                "reason": out.decision.reason,
            },
        )
        if state == BehaviourState.EMERGENCY_STOP:
            self.writer.add_event(record.t_s, EventKind.EMERGENCY_STOP, reason=out.decision.reason)
        self._state = state


def _estimate_columns(est: LocalizationEstimate) -> tuple[float, float, float, float, float, int]:
    """The localization table's estimate columns. An estimate whose numbers are not all finite is
    logged as invalid (its pose could not be trusted whatever its flag says), with NaN where they were
    not finite."""
    p = est.map_from_base
    values = (p.x_m, p.y_m, p.yaw_rad, est.pos_std_m, est.yaw_std_rad)
    finite = all(math.isfinite(v) for v in values)
    code = POSITION_SOURCES.index(est.source.value) if est.valid and finite else INVALID_SOURCE
    x, y, yaw, pos_std, yaw_std = (v if math.isfinite(v) else math.nan for v in values)
    return x, y, yaw, pos_std, yaw_std, code


class BlackBoxCallback(LoopCallback):
    """Keeps the black box's rolling window and makes it write on a takeover, a collision, an emergency
    stop, a minimal risk manoeuvre, a hardware-watchdog trip or a crash of the vehicle software (triggers
    close in time share one file); logs a ``recording`` event per file at the end."""

    def __init__(self, config: BlackBoxConfig, writer: RunLogWriter) -> None:
        self.box = BlackBox(config)
        self.writer = writer
        self._failing = False
        self._tripped = False
        self._state: BehaviourState | None = None
        self._level = FailSafeLevel.NONE

    def on_tick(self, record: TickRecord) -> None:
        box, now_us = self.box, int(record.now)
        if record.failure and not self._failing:
            box.dump("crash", reason=record.failure, now_us=now_us)
        self._failing = bool(record.failure)
        box.record_frames(now_us, record.frames)
        out, directive = record.output, record.verdict.directive
        if out is not None:
            box.record_output(now_us, out)
            if directive.level != FailSafeLevel.NONE or directive.level != self._level:
                box.record(now_us, "/safety/directive", directive)
        if out is not None and out.decision is not None and record.state != self._state:
            if record.state == BehaviourState.EMERGENCY_STOP:
                box.trigger("emergency_stop", now_us, out.decision.reason)
            self._state = record.state
        if directive.level != self._level:
            if directive.level == FailSafeLevel.MINIMAL_RISK_MANOEUVRE:
                box.trigger("mrm", now_us, "; ".join(directive.reasons))
            self._level = directive.level
        if record.verdict.watchdog_tripped and not self._tripped:
            box.trigger("watchdog", now_us, "hardware watchdog: no fresh command from the stack")
        self._tripped = record.verdict.watchdog_tripped
        for _, kind, data in record.events:
            if kind in BLACK_BOX_TRIGGERS:
                box.trigger(kind, now_us, str(data))

    def on_end(self, loop: ClosedLoop[Any], ticks_run: int) -> None:
        if loop.interrupted and ticks_run > 0:
            # The user stopped the run, often because something looked wrong: keep the last window.
            self.box.dump("manual", reason="run interrupted (Ctrl-C or SIGTERM)")
        self.box.close()
        for path in sorted(self.box.dumps):
            # blackbox_<trigger>_<t>s_<n>.mcap; the trigger may itself hold underscores (emergency_stop).
            head, t_text, _ = path.stem.rsplit("_", 2)
            trigger = head.removeprefix("blackbox_")
            self.writer.add_event(
                float(t_text.rstrip("s")),
                EventKind.RECORDING,
                path=str(path),
                trigger=trigger,
                triggers=list(self.box.dump_triggers.get(path, (trigger,))),
            )


class LiveViewCallback(LoopCallback):
    """Serves the run live (Foxglove WebSocket): the black box's channels, as each tick happens.

    With ``realtime`` the loop waits for the wall clock whenever it runs ahead of it, so a viewer sees
    the run at its own pace (waiting only: a loop slower than real time is never hurried).
    """

    def __init__(self, live: LiveView, realtime: bool = True) -> None:
        self.live = live
        self.realtime = realtime
        self._wall0 = 0.0
        self._level: FailSafeLevel | None = None

    def on_start(self, loop: ClosedLoop[Any]) -> None:
        self._wall0 = time.perf_counter()

    def on_tick(self, record: TickRecord) -> None:
        live, now_us = self.live, int(record.now)
        live.record_frames(now_us, record.frames)
        if record.output is not None:
            live.record_output(now_us, record.output)
        directive = record.verdict.directive
        if directive.level != self._level:
            live.record(now_us, "/safety/directive", directive)
            self._level = directive.level
        if self.realtime:
            ahead_s = record.t_s - (time.perf_counter() - self._wall0)
            if ahead_s > 0:
                time.sleep(ahead_s)

    def on_end(self, loop: ClosedLoop[Any], ticks_run: int) -> None:
        self.live.close()


class ProgressCallback(LoopCallback):
    """Reports simulated progress every :data:`PROGRESS_EVERY_TICKS` ticks and at the end."""

    def __init__(self, progress: ProgressFn, duration_s: float) -> None:
        self.progress = progress
        self.duration_s = duration_s

    def on_tick(self, record: TickRecord) -> None:
        if record.tick % PROGRESS_EVERY_TICKS == 0:
            self.progress(record.t_s, self.duration_s)

    def on_end(self, loop: ClosedLoop[Any], ticks_run: int) -> None:
        if not loop.interrupted:
            self.progress(self.duration_s, self.duration_s)


class TimingCallback(LoopCallback):
    """Wall-clock and CPU time of the run and of the vehicle software (reports only, never decisions)."""

    def __init__(self) -> None:
        self.software_s = 0.0
        self._wall0 = 0.0
        self._cpu0 = 0.0
        self.timing: dict[str, Any] = {}

    def on_start(self, loop: ClosedLoop[Any]) -> None:
        self._wall0, self._cpu0 = time.perf_counter(), time.process_time()

    def on_tick(self, record: TickRecord) -> None:
        self.software_s += record.software_s

    def on_end(self, loop: ClosedLoop[Any], ticks_run: int) -> None:
        wall = time.perf_counter() - self._wall0
        cpu = time.process_time() - self._cpu0
        simulated_s = ticks_run * loop.tick_us / 1e6
        report = loop.software.report()
        # Warm-up (each module's first call, and calls during which Numba compiled) is apart: a user
        # starting the shuttle once and driving for hours never sees it again.
        warmup = sum(float(m.get("warmup_ms") or 0.0) for m in report.modules.values()) / 1e3
        # The CPU factor leaves out the warm-up's CPU time (its wall time also counts the other
        # processes' turns: on a loaded machine it would take more than the warm-up cost).
        warmup_cpu = sum(
            float(m.get("warmup_cpu_ms", m.get("warmup_ms")) or 0.0) for m in report.modules.values()
        )
        warmup_cpu /= 1e3
        steady, steady_cpu = wall - warmup, cpu - warmup_cpu
        self.timing = {
            "wall_s": wall,
            "warmup_s": warmup,
            "warmup_cpu_s": warmup_cpu,
            "realtime_factor": simulated_s / steady if steady > 0 else None,
            "realtime_factor_with_warmup": simulated_s / wall if wall > 0 else None,
            # CPU seconds of this process: the one-core figure when other work shares the machine.
            "cpu_s": cpu,
            "realtime_factor_cpu": simulated_s / steady_cpu if steady_cpu > 0 else None,
            "stack_wall_s": self.software_s,
            "stack_tick_mean_ms": 1e3 * self.software_s / max(ticks_run, 1),
            "modules": report.modules,
            "stack_counters": dict(report.counters),
        }
        if report.perception:
            self.timing["raw_perception"] = dict(report.perception)


RUN_METADATA = "lastmile_run"
"""The metadata record of every black-box file that says what produced the run (scenario and run
configuration as TOML): ``lastmile replay --through-stack`` rebuilds the stack from it."""


def black_box_config(
    out_dir: Path,
    window_s: float,
    world: Simulation,
    calibration: SensorCalibration,
    run: tuple[Scenario, RunConfig] | None = None,
) -> BlackBoxConfig:
    """The black box of a run writing into ``out_dir``, keeping ``window_s`` seconds.

    Its ``/tf`` places every sensor at its true mount (the vehicle's calibration: the simulated
    sensors' own), and it draws the HD map the vehicle drives on and its service route. With ``run``
    (the scenario and the run configuration), each file says what produced it (:data:`RUN_METADATA`).
    """
    metadata = {}
    if run is not None:
        metadata[RUN_METADATA] = {
            "scenario_toml": scenario_to_toml(run[0]),
            "run_config_toml": run_config_to_toml(run[1]),
        }
    return BlackBoxConfig(
        out_dir=out_dir,
        window_us=round(window_s * 1e6),
        sensor_mounts=sensor_frame_mounts(calibration),
        map_lines=map_polylines(world.world.hdmap),
        route=np.asarray(world.service_route.xy_m),
        metadata=metadata,
    )


def sensor_frame_mounts(calibration: SensorCalibration) -> dict[str, np.ndarray]:
    """(4, 4) base_from_sensor of every sensor by its frame id in recordings (``foxglove_views``)."""
    mounts: dict[str, np.ndarray] = {}
    for sensor_id, se2 in calibration.radar_mounts.items():
        mounts[f"radar_{sensor_id}"] = planar_matrix(se2.x_m, se2.y_m, se2.yaw_rad)
    for sensor_id, matrix in calibration.lidar_mounts.items():
        mounts[f"lidar_{sensor_id}"] = np.asarray(matrix, dtype=float)
    for prefix, cameras in (("camera", calibration.cameras), ("light_camera", calibration.light_cameras)):
        for cam in cameras:
            # The camera model holds camera_from_base (optical frame); /tf wants base -> camera.
            mounts[f"{prefix}_{cam.camera_id}"] = np.linalg.inv(cam.camera_from_base)
    return mounts


def map_polylines(hdmap: HDMap) -> tuple[np.ndarray, ...]:
    """The map's lane boundaries (each shared bound once), stop lines and crosswalk outlines."""
    lines: dict[tuple[int, str], np.ndarray] = {}
    for ll in hdmap.lanelets.values():
        for side, bound, bound_id in (("l", ll.left, ll.left_bound_id), ("r", ll.right, ll.right_bound_id)):
            key = (bound_id, "") if bound_id else (ll.id, side)
            lines.setdefault(key, np.asarray(bound.xy_m))
    out = list(lines.values())
    out.extend(np.asarray(sl.line)[:, :2] for sl in hdmap.stop_lines)
    for cw in hdmap.crosswalks:
        poly = np.asarray(cw.polygon)[:, :2]
        out.append(np.vstack([poly, poly[:1]]))
    return tuple(out)


def live_view_config(
    host: str, port: int, world: Simulation, calibration: SensorCalibration
) -> LiveViewConfig:
    """The live view of a run: the black box's sensor mounts, map and route, served at ``host:port``."""
    return LiveViewConfig(
        host=host,
        port=port,
        sensor_mounts=sensor_frame_mounts(calibration),
        map_lines=map_polylines(world.world.hdmap),
        route=np.asarray(world.service_route.xy_m),
    )
