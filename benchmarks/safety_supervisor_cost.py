"""Safety chain cost beside the real closed loop: monitors + arbiter + gate per tick vs the stack's own tick.

Run: python benchmarks/safety_supervisor_cost.py [--seconds 120] [--seeds 0 1] [--json out.json]

The default campus service runs in the loop engine with its vehicle safety (five modules' heartbeats,
the sensor streams, map / route ODD checks, the actuator gate and the hardware watchdog), which runs
apart from the stack. Reported
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

from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import SafetyVerdict, StackOutput
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.run_config import RunConfig
from lastmile.safety.vehicle_safety import VehicleSafety
from lastmile.sim.scenario import default_service

CONFIG = RunConfig().with_perception(PerceptionMode.RADAR_TRACKING)


class TimedSafety:
    """The loop's vehicle safety with a stopwatch on both of its phases (observe and step)."""

    def __init__(self, inner: VehicleSafety) -> None:
        self.inner = inner
        self.ns: list[int] = []
        self.signals: Counter[str] = Counter()
        self._observe_ns = 0

    @property
    def directive(self):  # type: ignore[no-untyped-def]
        return self.inner.directive

    def observe(self, now: Stamp, frames: list[SensorFrame]) -> None:
        t0 = time.perf_counter_ns()
        self.inner.observe(now, frames)
        self._observe_ns = time.perf_counter_ns() - t0

    def step(self, now: Stamp, output: StackOutput | None, failure: str = "") -> SafetyVerdict:
        t0 = time.perf_counter_ns()
        verdict = self.inner.step(now, output, failure)
        self.ns.append(self._observe_ns + time.perf_counter_ns() - t0)
        self.signals.update(s.kind.value for s in self.inner.supervisor.last_signals)
        return verdict


def run(seed: int, seconds: float) -> dict[str, object]:
    scenario = dataclasses.replace(default_service(seed=seed), minutes=seconds / 60.0)
    loop = build_closed_loop(scenario, CONFIG)
    timed = TimedSafety(loop.safety)
    loop.safety = timed  # type: ignore[assignment]
    stack_s = [r.software_s for r in loop.ticks(round(seconds * 1e6 / CONFIG.loop.tick_us))]
    safety_us = np.asarray(timed.ns) / 1e3
    stack_us = np.asarray(stack_s) * 1e6
    return {
        "seed": seed,
        "safety_p50_us": float(np.percentile(safety_us, 50)),
        "safety_p95_us": float(np.percentile(safety_us, 95)),
        "safety_mean_us": float(safety_us.mean()),
        "stack_mean_us": float(stack_us.mean()),
        "safety_share_of_stack": float(safety_us.mean() / stack_us.mean()),
        "signals": dict(timed.signals),
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
