"""Safety chain cost beside the real closed loop: monitors + arbiter + gate per tick vs the stack's own tick.

Run: python benchmarks/safety_supervisor_cost.py [--seconds 120] [--seeds 0 1] [--json out.json]

The default campus service runs with a SafetySupervisor (five modules' heartbeats, six sensor streams,
map / route ODD checks), the actuator gate and the hardware watchdog fed from outside the stack. Reported
per 10 ms tick: the safety chain's wall time (median, p95) and the stack's own tick time, as a ratio, plus
the malfunctions raised (a healthy run should raise none). There is no library to compare against: the
reference is the stack it protects. One core, BLAS one thread.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import time
from collections import Counter
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from lastmile.core.safety_messages import FailSafeLevel
from lastmile.core.stamp import Stamp
from lastmile.runner.closed_loop import TICK_US, build_closed_loop
from lastmile.safety.failsafe import FailSafeArbiter, apply_safety_gate
from lastmile.safety.hardware_watchdog import HardwareWatchdog
from lastmile.safety.health_monitor import HealthMonitor, ModuleSpec
from lastmile.safety.reliability_config import ReliabilityConfig, SensorSpec
from lastmile.safety.reliability_monitor import ReliabilityMonitor
from lastmile.safety.supervisor import SafetySupervisor
from lastmile.sim.scenario import default_service

SENSORS = (
    SensorSpec(key="gnss", rate_hz=10.0),
    SensorSpec(key="imu", rate_hz=50.0, frozen_after=5),
    SensorSpec(key="odom", rate_hz=50.0, frozen_after=None),
    SensorSpec(key="door", rate_hz=10.0, frozen_after=None),
    SensorSpec(key="front", rate_hz=20.0),
    SensorSpec(key="rear", rate_hz=20.0, silent_level=FailSafeLevel.SPEED_LIMIT),
)
MODULES = ("localization", "tracking", "decision", "planning", "control")


def run(seed: int, seconds: float) -> dict[str, object]:
    scenario = dataclasses.replace(default_service(seed=seed), minutes=seconds / 60.0)
    hdmap, sim, stack = build_closed_loop(scenario, "radar_tracking")
    sup = SafetySupervisor(
        HealthMonitor([ModuleSpec(name=m, period_us=100_000) for m in MODULES]),
        ReliabilityMonitor(ReliabilityConfig(sensors=SENSORS), hdmap=hdmap, route=stack.route),
        FailSafeArbiter(layers=stack.layers),
    )
    watchdog = HardwareWatchdog()
    safety_ns: list[int] = []
    stack_ns: list[int] = []
    signals: Counter[str] = Counter()
    clock = time.perf_counter_ns
    for tick in range(round(seconds * 1e6 / TICK_US)):
        now = Stamp(tick * TICK_US)
        sim.advance_world(tick)
        frames = sim.sensor_frames(tick)
        t0 = clock()
        sup.observe_frames(now, frames)
        t1 = clock()
        out = stack.tick(now, frames)
        t2 = clock()
        est = stack.ekf.estimate(now) if tick % 10 == 0 else None
        speed = stack.ekf.estimate(now).speed_mps
        t3 = clock()
        directive = sup.step(
            now, out.heartbeats, estimate=est, gate_rejections_total=stack.ekf.rejected_fixes, speed_mps=speed
        )
        assert out.command is not None
        command = apply_safety_gate(out.command, directive, speed)
        command = watchdog.observe(now, command) or command
        t4 = clock()
        safety_ns.append((t1 - t0) + (t4 - t3))
        stack_ns.append(t2 - t1)
        signals.update(s.kind.value for s in sup.last_signals)
        sim.apply_command(command)
        sim.referee(out.takeover_request or directive.takeover_request)
    safety_us = np.asarray(safety_ns) / 1e3
    stack_us = np.asarray(stack_ns) / 1e3
    return {
        "seed": seed,
        "safety_p50_us": float(np.percentile(safety_us, 50)),
        "safety_p95_us": float(np.percentile(safety_us, 95)),
        "safety_mean_us": float(safety_us.mean()),
        "stack_mean_us": float(stack_us.mean()),
        "safety_share_of_stack": float(safety_us.mean() / stack_us.mean()),
        "signals": dict(signals),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/safety_supervisor_cost.json"))
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    rows = [run(seed, args.seconds) for seed in args.seeds]
    table = Table(title=f"safety chain per 10 ms tick, default service, {args.seconds:g} s, one core")
    for col in (
        "seed",
        "safety p50 µs",
        "safety p95 µs",
        "safety mean µs",
        "stack mean µs",
        "safety / stack",
        "signals",
    ):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            str(r["seed"]),
            f"{r['safety_p50_us']:.1f}",
            f"{r['safety_p95_us']:.1f}",
            f"{r['safety_mean_us']:.1f}",
            f"{r['stack_mean_us']:.1f}",
            f"{r['safety_share_of_stack']:.2f}",
            str(sum(r["signals"].values())),  # type: ignore[union-attr]
        )
    Console().print(table)
    med = {
        key: statistics.median(float(r[key]) for r in rows)  # type: ignore[arg-type]
        for key in (
            "safety_p50_us",
            "safety_p95_us",
            "safety_mean_us",
            "stack_mean_us",
            "safety_share_of_stack",
        )
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps({"seconds": args.seconds, "median_over_seeds": med, "runs": rows}, indent=2)
    )
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
