"""Localization modes through a GNSS outage in closed loop: lateral error, ATE and compute per update.

Run: python benchmarks/localization_modes.py [--weather snow] [--outage 140:60] [--minutes 3.7]
         [--scenario FILE] [--drive landmarks] [--seed 0] [--out DIR] [--json out.json]
         [--map MAP.pcd | --map-minutes 10 --map-recording FILE]

The shuttle drives the campus service (or ``--scenario``) with the ``--drive`` localization mode and
raw LiDAR perception, through a GNSS outage (``--outage START:DURATION``, s; a scenario's own first
``[gnss]`` outage when ``--scenario`` is given). Beside the driving mode, every other runnable mode is
fed the very frames the vehicle received (a shadow filter: same trajectory, so the modes compare on
equal terms):

- ``landmarks``: the stack's own estimate when it drives (poles and facades from the raw LiDAR chain,
  fused by the inertial EKF);
- ``ekf`` and ``inertial_ekf``: the GNSS/INS EKFs, which are dead reckoning through the outage (the
  dead-reckoning baseline the issue asks for);
- ``scan_matching`` (``--drive scan_matching``): the stack's own estimate, each LiDAR frame registered to
  a point-cloud map. The map is ``--map``, or built here the way a user builds it: a mapping drive of
  ``--map-minutes`` on the campus in clear weather with another seed (``--seed`` + 1: other traffic,
  other sensor noise) recorded with ``LidarMapRecording`` (a rig frame per 2 m of the stack's own
  estimated travel) and ``lastmile map build``'s ``build_map`` on that recording; the map's sidecar
  is printed;
- ``amcl`` (``--drive amcl``): the stack's own estimate, NUS's particle filter on the occupancy map that
  ``map build`` writes beside the point-cloud map (``--map``'s ``.yaml``, or the one built here).

One run drives one mode (the others of the map family are rows of their own runs: ``--drive``).

Printed per mode: lateral error p95 and max through the outage (truth vs estimate, rear axle), ATE (RMS
position error) through the outage and over the run, the share of the outage the estimate's source was
the map (LANDMARKS or SCAN_MATCHING) / DEAD_RECKONING, and the compute time per update (median): for
``landmarks`` one LiDAR frame's extraction, association and EKF update (the stack profiler's
``landmarks`` module), for ``scan_matching`` one frame's registration, checks and EKF update, for the
EKFs one input (a wheel-speed/IMU prediction or a GNSS fix), as this thread's CPU time (the wall time
on a shared machine also counts other processes; the stack profiler's wall p50 is printed beside it).
Reference operations in the same run: a 9x9 float64 matrix product (the filters' elementary step, CPU
time) and the LiDAR chain's own wall median per frame.
Also the closed-loop outcome (collisions, takeovers, stops served, mean speed through the outage) from
the run's metrics. Targets (issue 19): lateral p95 <= 0.10 m with landmarks through the outage, each
update under 10 ms median on one core.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.sensor_frames import GnssInsFrame, ImuFrame, WheelOdometryFrame
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.localization.amcl_localization import AmclSettings
from lastmile.localization.ekf import PoseEkf
from lastmile.localization.map_build import MapBuildConfig
from lastmile.localization.odometry_ekf import OdometryEkf
from lastmile.localization.point_cloud_map import read_sidecar
from lastmile.localization.scan_match_localization import ScanMatchingSettings
from lastmile.runner.closed_loop import evaluate_run, run_scenario
from lastmile.runner.loop import ClosedLoop, LoopCallback, TickRecord
from lastmile.runner.map_build_replay import build_map
from lastmile.runner.map_recording import LidarMapRecording
from lastmile.runner.run_config import RunConfig
from lastmile.sim.gnss_scenario import GnssOutage, GnssScenario
from lastmile.sim.scenario import Scenario, load_scenario
from lastmile.stack.stack_settings import LocalizationMode

MAP_MODES = ("landmarks", "scan_matching", "amcl")
MAP_SOURCES = (PositionSource.LANDMARKS, PositionSource.SCAN_MATCHING, PositionSource.AMCL)


CLOSED_LOOP_KEYS = ("collisions_total", "takeovers", "stops_served", "emergency_stops", "mean_speed_mps")


class ShadowMode:
    """A localization filter fed the frames the vehicle received, timed per input."""

    def __init__(self, ekf: OdometryEkf | PoseEkf) -> None:
        self.ekf = ekf
        self.yaw_rate_radps = 0.0
        self.times_s: list[float] = []

    def feed(self, frame: object) -> None:
        ekf = self.ekf
        start = time.thread_time()
        if isinstance(frame, GnssInsFrame):
            ekf.update_gnss(frame)
        elif isinstance(frame, ImuFrame):
            self.yaw_rate_radps = frame.yaw_rate_radps
            if isinstance(ekf, PoseEkf):
                ekf.imu(frame.stamp, frame.yaw_rate_radps, frame.accel_x_mps2)
            else:
                return
        elif isinstance(frame, WheelOdometryFrame):
            if isinstance(ekf, PoseEkf):
                ekf.wheel_speed(frame.stamp, frame.speed_mps)
            else:
                ekf.predict(frame.stamp, frame.speed_mps, self.yaw_rate_radps)
        else:
            return
        self.times_s.append(time.thread_time() - start)


class ModeProbe(LoopCallback):
    """Truth beside each mode's estimate on every planning cycle (benchmark only: reads the truth)."""

    def __init__(self, shadows: dict[str, ShadowMode], drive_name: str) -> None:
        self.shadows = shadows
        self.drive_name = drive_name
        self.loop: ClosedLoop[Any] | None = None
        self.rows: dict[str, list[tuple[float, ...]]] = {drive_name: [], **{k: [] for k in shadows}}
        self.report: Any = None

    def on_start(self, loop: ClosedLoop[Any]) -> None:
        self.loop = loop

    def on_end(self, loop: ClosedLoop[Any], ticks_run: int) -> None:
        self.report = loop.software.report()

    def on_tick(self, record: TickRecord) -> None:
        for frame in record.frames:
            for shadow in self.shadows.values():
                shadow.feed(frame)
        est = record.output.diagnostics.estimate if record.output is not None else None
        if est is None or self.loop is None:
            return
        truth = self.loop.world.ego_state
        self._row(self.drive_name, record.t_s, truth, est)
        for name, shadow in self.shadows.items():
            self._row(name, record.t_s, truth, shadow.ekf.estimate(record.now))

    def _row(self, name: str, t_s: float, truth: Any, est: LocalizationEstimate) -> None:
        pose = est.map_from_base
        dx, dy = pose.x_m - truth.x_m, pose.y_m - truth.y_m
        c, s = math.cos(truth.yaw_rad), math.sin(truth.yaw_rad)
        self.rows[name].append(
            (
                t_s,
                -s * dx + c * dy,
                c * dx + s * dy,
                est.pos_std_m,
                float(est.source in MAP_SOURCES),
                float(est.source is PositionSource.DEAD_RECKONING),
                float(est.valid),
                truth.speed_mps,
            )
        )


def matrix_product_us(repeats: int = 2000) -> float:
    """Median CPU time of one 9x9 float64 matrix product (the filters' elementary step), µs."""
    a = np.random.default_rng(0).standard_normal((9, 9))
    times = []
    for _ in range(repeats):
        t0 = time.thread_time()
        a @ a
        times.append(time.thread_time() - t0)
    return statistics.median(times) * 1e6


def summarise(rows: list[tuple[float, ...]], t0_s: float, t1_s: float) -> dict[str, float]:
    a = np.array(rows)
    out = (a[:, 0] >= t0_s) & (a[:, 0] < t1_s)
    run = a[:, 0] >= 10.0  # after the filters' start-up
    lat = np.abs(a[out, 1])
    pos = np.hypot(a[:, 1], a[:, 2])
    return {
        "lateral_p95_m": float(np.percentile(lat, 95)),
        "lateral_max_m": float(lat.max()),
        "ate_outage_m": float(np.sqrt(np.mean(pos[out] ** 2))),
        "ate_run_m": float(np.sqrt(np.mean(pos[run] ** 2))),
        "sigma_end_of_outage_m": float(a[out, 3][-1]),
        "share_map_held": float(a[out, 4].mean()),
        "share_dead_reckoning": float(a[out, 5].mean()),
        "share_valid": float(a[out, 6].mean()),
        "mean_speed_outage_mps": float(a[out, 7].mean()),
    }


def scenario_for(args: argparse.Namespace) -> tuple[Scenario, float, float]:
    if args.scenario:
        scenario = load_scenario(Path(args.scenario))
        first = scenario.gnss.outages[0]
        start_s, duration_s = first.start_s, first.duration_s
    else:
        start_s, duration_s = (float(v) for v in args.outage.split(":"))
        scenario = Scenario(
            name="localization_modes",
            gnss=GnssScenario(
                outages=(GnssOutage(start_s=start_s, duration_s=duration_s),), wheel_slip_on_snow=True
            ),
        )
    minutes = args.minutes if args.minutes is not None else (start_s + duration_s + 20.0) / 60.0
    scenario = dataclasses.replace(
        scenario, weather=args.weather or scenario.weather, minutes=minutes, seed=args.seed
    )
    return scenario, start_s, duration_s


def point_cloud_map(args: argparse.Namespace) -> tuple[Path, dict[str, Any]]:
    """``--map``, or a map built from a mapping drive recorded here (clear weather, seed + 1)."""
    if args.map:
        path = Path(args.map)
        side = read_sidecar(path)
        return path, {"path": str(path), "sidecar": side}
    folder = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="lastmile_map_"))
    recording_path = Path(args.map_recording) if args.map_recording else folder / "mapping_drive.mcap"
    drive = Scenario(name="mapping_drive", minutes=args.map_minutes, seed=args.seed + 1)
    recording = LidarMapRecording(recording_path, min_travel_m=2.0)
    cpu0 = time.process_time()
    run_scenario(drive, RunConfig(), extra_callbacks=(recording,))
    cpu_drive = time.process_time() - cpu0
    path = folder / "campus_map.pcd"
    cpu0 = time.process_time()
    result = build_map(recording_path, path, MapBuildConfig())
    return path, {
        "path": str(path),
        "mapping_drive": {"minutes": args.map_minutes, "seed": args.seed + 1, "weather": "clear"},
        "recording": str(recording_path),
        "rig_frames_recorded": recording.rig_frames,
        "drive_cpu_s": cpu_drive,
        "build_cpu_s": time.process_time() - cpu0,
        "sidecar": dataclasses.asdict(result.info),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", default="")
    p.add_argument("--weather", default="snow")
    p.add_argument("--outage", default="140:60")
    p.add_argument("--minutes", type=float, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--drive", default="landmarks", choices=[m.value for m in LocalizationMode])
    p.add_argument("--out", default="")
    p.add_argument("--json", default="")
    p.add_argument("--map", default="", help="scan_matching: the point-cloud map (else built here)")
    p.add_argument("--map-minutes", type=float, default=10.0, help="the mapping drive, simulated minutes")
    p.add_argument("--map-recording", default="", help="keep the mapping drive's recording here")
    args = p.parse_args()
    scenario, start_s, duration_s = scenario_for(args)
    base = RunConfig()
    map_info: dict[str, Any] | None = None
    extra: dict[str, Any] = {}
    if args.drive == LocalizationMode.SCAN_MATCHING.value:
        map_path, map_info = point_cloud_map(args)
        extra["scan_matching"] = ScanMatchingSettings(map=str(map_path))
    elif args.drive == LocalizationMode.AMCL.value:
        map_path, map_info = point_cloud_map(args)
        extra["amcl"] = AmclSettings(map=str(map_path.with_suffix(".yaml")))
    stack = dataclasses.replace(
        base.stack,
        localization=LocalizationMode(args.drive),
        perception=PerceptionMode.LIDAR_CAMERA_RADAR,
        **extra,
    )
    config = dataclasses.replace(base, stack=stack)
    # The shadows' filters are configured as the stack configures its own (zero-slip point of an
    # all-wheel-steer shuttle at mid-wheelbase).
    geometry = VehicleGeometry()
    zero_slip_m = geometry.wheelbase_m / 2.0 if geometry.all_wheel_steer else 0.0
    shadows = {
        "ekf": ShadowMode(OdometryEkf(dataclasses.replace(config.stack.ekf, zero_slip_offset_m=zero_slip_m))),
        "inertial_ekf": ShadowMode(
            PoseEkf(dataclasses.replace(config.stack.inertial_ekf, zero_slip_offset_m=zero_slip_m))
        ),
    }
    shadows.pop(args.drive, None)
    probe = ModeProbe(shadows, args.drive)
    load_before = os.getloadavg()
    wall0 = time.perf_counter()
    log = run_scenario(scenario, config, extra_callbacks=(probe,))
    wall_s = time.perf_counter() - wall0
    out_dir = Path(args.out) if args.out else None
    metrics = evaluate_run(log, out_dir) if out_dir is not None else {}
    ref_us = matrix_product_us()
    modules = probe.report.modules
    results: dict[str, Any] = {}
    for name, rows in probe.rows.items():
        r = summarise(rows, start_s, start_s + duration_s)
        if name in shadows:
            r["update_cpu_median_ms"] = statistics.median(shadows[name].times_s) * 1e3
        elif name == LocalizationMode.LANDMARKS.value and "landmarks" in modules:
            r["update_median_ms"] = modules["landmarks"]["p50_ms"]
            r["update_cpu_median_ms"] = probe.report.perception.get("landmark_update_cpu_p50_ms")
        elif name == LocalizationMode.SCAN_MATCHING.value and "scan_matching" in modules:
            r["update_median_ms"] = modules["scan_matching"]["p50_ms"]
            r["update_cpu_median_ms"] = probe.report.perception.get("scan_match_update_cpu_p50_ms")
        elif name == LocalizationMode.AMCL.value and "amcl" in modules:
            r["update_median_ms"] = modules["amcl"]["p50_ms"]
            r["update_cpu_median_ms"] = probe.report.perception.get("amcl_update_cpu_p50_ms")
        results[name] = r
    report = {
        "scenario": scenario.name,
        "weather": scenario.weather,
        "seed": args.seed,
        "outage_s": [start_s, duration_s],
        "drive_mode": args.drive,
        "modes": results,
        "not_run": {m: f"run with --drive {m}" for m in MAP_MODES if m != args.drive},
        "map": map_info,
        "reference": {
            "matrix_9x9_product_us": ref_us,
            "lidar_chain_p50_ms": modules.get("perception", {}).get("p50_ms"),
        },
        "stack_counters": dict(probe.report.counters),
        "closed_loop": {
            k: metrics.get(k) for k in ("collisions_total", "takeovers", "stops_served", "emergency_stops")
        },
        "load_avg_1_5_15": [load_before, os.getloadavg()],
        "wall_s": wall_s,
    }
    print_table(report)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
        # The series behind the table: t_s, lateral, longitudinal error, sigma, landmarks, dead
        # reckoning, valid, true speed per planning cycle and mode.
        np.savez_compressed(
            Path(args.json).with_suffix(".npz"), **{k: np.array(v) for k, v in probe.rows.items()}
        )


def print_table(report: dict[str, Any]) -> None:
    console = Console(width=180)
    start_s, duration_s = report["outage_s"]
    where = f"{report['scenario']} ({report['weather']}, seed {report['seed']})"
    t = Table(
        title=f"{where}, GNSS outage {start_s:.0f} s + {duration_s:.0f} s, driven by '{report['drive_mode']}'"
    )
    for col in (
        "mode",
        "lat p95 m",
        "lat max m",
        "ATE outage m",
        "ATE run m",
        "map-held",
        "dead reck.",
        "update CPU ms",
        "x 9x9 matmul",
        "update wall ms",
        "speed in outage m/s",
    ):
        t.add_column(col)
    ref_us = report["reference"]["matrix_9x9_product_us"]
    for name, r in report["modes"].items():
        ms, wall_ms = r.get("update_cpu_median_ms"), r.get("update_median_ms")
        t.add_row(
            name,
            f"{r['lateral_p95_m']:.3f}",
            f"{r['lateral_max_m']:.3f}",
            f"{r['ate_outage_m']:.3f}",
            f"{r['ate_run_m']:.3f}",
            f"{r['share_map_held']:.0%}",
            f"{r['share_dead_reckoning']:.0%}",
            "-" if ms is None else f"{ms:.3f}",
            "-" if ms is None else f"{ms * 1e3 / ref_us:.0f}",
            "-" if wall_ms is None else f"{wall_ms:.3f}",
            f"{r['mean_speed_outage_mps']:.2f}",
        )
    console.print(t)
    if report.get("map"):
        console.print(f"map: {report['map']}")
    for name, why in report["not_run"].items():
        console.print(f"{name}: not in this run: {why}")
    chain_ms = report["reference"]["lidar_chain_p50_ms"]
    console.print(f"reference: 9x9 matmul {ref_us:.2f} µs, LiDAR chain p50 {chain_ms:.1f} ms per frame")
    console.print(f"closed loop: {report['closed_loop']}; stack counters: {report['stack_counters']}")
    console.print(f"load average before/after: {report['load_avg_1_5_15']}; wall {report['wall_s']:.0f} s")


if __name__ == "__main__":
    main()
