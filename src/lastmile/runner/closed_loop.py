"""Runs one scenario with one run configuration in closed loop, and writes the run directory."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.vehicle import VehicleGeometry
from lastmile.evaluation.metrics import compute_metrics, write_metrics, write_timing
from lastmile.evaluation.report import write_report
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.model import HDMap
from lastmile.hdmap.service_route import ServiceRoute, campus_service, load_route
from lastmile.recorder.live_view import LiveView
from lastmile.recorder.run_log import RunLog, RunMeta
from lastmile.recorder.run_log_writer import RunLogWriter
from lastmile.runner.loop import ClosedLoop, LoopCallback
from lastmile.runner.loop_callbacks import (
    BlackBoxCallback,
    LiveViewCallback,
    ProgressCallback,
    ProgressFn,
    RunLogCallback,
    TimingCallback,
    black_box_config,
    live_view_config,
)
from lastmile.runner.run_config import RunConfig, run_config_dict
from lastmile.sim.camera import default_cameras
from lastmile.sim.scenario import MapSpec, Scenario
from lastmile.sim.simulation import Simulation
from lastmile.stack.stack_settings import StackSettings
from lastmile.stack.vehicle_build import SensorCalibration, build_vehicle

DEFAULT_CONFIG = RunConfig()
"""The default run configuration: raw LiDAR + camera + radar perception, WATonoBus's controllers."""


def load_world_map(spec: MapSpec) -> ServiceRoute:
    """The map and service route of a scenario's ``[map]`` section."""
    if spec.name == "route":
        return load_route(spec.route)
    return campus_service()


def build_closed_loop(
    scenario: Scenario,
    config: RunConfig = DEFAULT_CONFIG,
    callbacks: tuple[LoopCallback, ...] = (),
) -> ClosedLoop[Simulation]:
    """The world of ``scenario``, a vehicle configured by ``config``, joined in one loop.

    The vehicle gets the map and its own configuration (and, as a real vehicle's software is
    configured with them, the sensors' mounts), never the simulator's objects.
    """
    config.check_serves(scenario)
    service = load_world_map(scenario.map)
    hdmap = service.hdmap
    service_route = service.polyline
    geometry = VehicleGeometry()
    tick_us = config.loop.tick_us
    world = Simulation(
        scenario,
        hdmap,
        service_route,
        geometry,
        tick_us,
        raw_sensors=config.stack.perception.needs_raw_sensors,
        map_speed_limits=scenario.map.name == "route",
        unmapped_speed_limit_mps=service.unmapped_speed_limit_mps,
    )
    layers = service.layers(step_m=1.0)
    vehicle = build_vehicle(
        layers,
        geometry,
        config.stack,
        sensor_calibration(world, config.stack),
        tick_us,
        # Module faults of the scenario reach the stack through its fault-injection port.
        fault_hook=lambda module, now_us: world.faults.module_fault(module, now_us / 1e6),
    )
    return ClosedLoop(world, vehicle.software, vehicle.safety, tick_us, callbacks)


def sensor_calibration(world: Simulation, stack: StackSettings | None = None) -> SensorCalibration:
    """The vehicle's calibration: the simulated sensors' true mounts (a real vehicle's nominal ones),
    the LiDARs' replaced by the mounts file of ``stack.lidar_mounts`` and the cameras' by that of
    ``stack.camera_mounts`` where one is given.

    Raises:
        ConfigError: a file does not name exactly the rig's LiDARs or the vehicle's cameras.
    """
    rig = world.raw_sensors
    lidar_mounts = {s.sensor_id: s.base_from_sensor for s in rig.lidar_specs} if rig else {}
    calibrated = stack.calibrated_lidar_mounts(tuple(lidar_mounts)) if stack is not None else None
    if calibrated is not None:
        lidar_mounts = calibrated
    cameras = tuple(c.camera for c in rig.cameras) if rig else ()
    light_cameras = world.light_cameras.cameras
    # The vehicle carries its cameras whichever perception runs (radar mode builds no raw rig).
    carried = list(cameras) if rig else list(default_cameras(world.world.geometry))
    ids = tuple(sorted({c.camera_id for c in carried} | {c.camera_id for c in light_cameras}))
    camera_mounts = stack.calibrated_camera_mounts(ids) if stack is not None else None
    if camera_mounts is not None:
        cameras = _remounted(cameras, camera_mounts)
        light_cameras = _remounted(light_cameras, camera_mounts)
    return SensorCalibration(
        radar_mounts=world.radar_mounts,
        lidar_mounts=lidar_mounts,
        cameras=cameras,
        light_cameras=light_cameras,
    )


def _remounted(cameras: tuple[PinholeCamera, ...], mounts: dict[str, Any]) -> tuple[PinholeCamera, ...]:
    """The cameras with ``camera_from_base`` from ``mounts`` (their optical centres derived anew)."""
    return tuple(
        dataclasses.replace(c, camera_from_base=mounts[c.camera_id], centre_base_m=None) for c in cameras
    )


def run_meta(scenario: Scenario, config: RunConfig, map_name: str) -> RunMeta:
    """What produced a run: the scenario's fields at the top level (the evaluation reads some), the
    run configuration under ``run_config``."""
    return RunMeta(
        seed=scenario.seed,
        weather=scenario.weather,
        perception_mode=str(config.stack.perception),
        scenario_name=scenario.name,
        map_name=map_name,
        tick_s=config.loop.tick_us / 1e6,
        duration_s=scenario.minutes * 60.0,
        config={**_jsonable(asdict(scenario)), "run_config": run_config_dict(config)},
    )


def run_scenario(
    scenario: Scenario,
    config: RunConfig = DEFAULT_CONFIG,
    progress: ProgressFn | None = None,
    black_box_dir: Path | None = None,
    live: tuple[str, int] | None = None,
    on_live: Callable[[int], None] | None = None,
    stop: Callable[[], bool] | None = None,
    extra_callbacks: tuple[LoopCallback, ...] = (),
) -> RunLog:
    """Simulate ``scenario`` with ``config``; returns the run log (wall-clock figures in ``log.timing``).

    With ``black_box_dir`` (and the black box on in ``config.loop``), the black box keeps the last
    window and writes it there as MCAP on a takeover, an emergency stop, a collision or a crash of the
    vehicle software (``recording`` events say where). Ctrl-C, or ``stop()`` turning true between
    ticks (:class:`lastmile.runner.stop_signals.StopSignals`), ends the run early with what was done.
    With ``live`` (host, port), the same channels are served over Foxglove's WebSocket protocol as the
    run happens, paced to the wall clock; ``on_live`` is told the port once the server listens.
    ``extra_callbacks`` run after the run log's (probes of benchmarks).
    """
    with threadpool_limits(limits=1):  # small matrices: BLAS threads only compete with the loop
        loop = build_closed_loop(scenario, config)
        world = loop.world
        writer = RunLogWriter(run_meta(scenario, config, world.map_name))
        timing = TimingCallback()
        callbacks: list[LoopCallback] = [RunLogCallback(writer, world, scenario), timing]
        if black_box_dir is not None and config.loop.black_box:
            box = black_box_config(
                black_box_dir,
                config.loop.black_box_window_s,
                world,
                sensor_calibration(world, config.stack),
                run=(scenario, config),
            )
            callbacks.append(BlackBoxCallback(box, writer))
        if live is not None:
            calibration = sensor_calibration(world, config.stack)
            view = LiveView(live_view_config(live[0], live[1], world, calibration))
            if on_live is not None:
                on_live(view.port)
            callbacks.append(LiveViewCallback(view))
        if progress is not None:
            callbacks.append(ProgressCallback(progress, scenario.minutes * 60.0))
        callbacks.extend(extra_callbacks)
        loop.callbacks.extend(callbacks)
        loop.run(round(scenario.minutes * 60e6 / config.loop.tick_us), stop)
        if loop.interrupted:
            timing.timing["interrupted"] = True
        writer.set_timing(timing.timing)
        return writer.finish()


def evaluate_run(log: RunLog, run_dir: Path, hdmap: HDMap | None = None) -> dict[str, Any]:
    """Write the run directory: run log, metrics.json (with the configuration that produced it),
    timing.json, report.md with plots."""
    run_dir.mkdir(parents=True, exist_ok=True)
    log.save(run_dir)
    metrics = compute_metrics(log)
    write_metrics({**metrics, "configuration": log.meta.config}, run_dir)
    write_timing(log.timing, run_dir)
    write_report(log, metrics, run_dir, hdmap=hdmap if hdmap is not None else load_campus_map())
    return metrics


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value
