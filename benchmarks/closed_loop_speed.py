"""Closed-loop speed: real-time factor of the default service and the stack's compute time per tick.

Run: python benchmarks/closed_loop_speed.py [--minutes 10] [--seeds 0 1 2] [--json out.json]
One core (BLAS pinned to one thread). Reports medians over seeds; the target of issue #2 is a real-time
factor of at least 20 (simulated seconds per wall second).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from rich.console import Console
from rich.table import Table

from lastmile.runner.closed_loop import run_scenario
from lastmile.sim.scenario import default_service

TARGET_RTF = 20.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/closed_loop_speed.json"))
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    rows = []
    for seed in args.seeds:
        log = run_scenario(default_service(seed=seed, minutes=args.minutes))
        t = log.timing
        rows.append(
            {
                "seed": seed,
                "realtime_factor": t["realtime_factor"],
                "realtime_factor_cpu": t["realtime_factor_cpu"],
                "wall_s": t["wall_s"],
                "stack_tick_mean_ms": t["stack_tick_mean_ms"],
                "modules": t["modules"],
            }
        )
    median_rtf = statistics.median(r["realtime_factor"] for r in rows)
    median_rtf_cpu = statistics.median(r["realtime_factor_cpu"] for r in rows)
    table = Table(title=f"closed loop, default service, {args.minutes:g} simulated min, one core")
    for col in ("seed", "real-time factor (wall)", "(CPU time)", "wall s", "stack ms/tick", "vs target 20x"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            str(r["seed"]),
            f"{r['realtime_factor']:.1f}",
            f"{r['realtime_factor_cpu']:.1f}",
            f"{r['wall_s']:.1f}",
            f"{r['stack_tick_mean_ms']:.3f}",
            f"{r['realtime_factor'] / TARGET_RTF:.2f}",
        )
    table.add_row(
        "median", f"{median_rtf:.1f}", f"{median_rtf_cpu:.1f}", "", "", f"{median_rtf / TARGET_RTF:.2f}"
    )
    console = Console()
    console.print(table)
    modules = Table(title=f"stack modules (seed {rows[0]['seed']}), ms per call")
    for col in ("module", "p50", "p95", "max", "calls"):
        modules.add_column(col, justify="right")
    for name, m in rows[0]["modules"].items():
        modules.add_row(
            name, f"{m['p50_ms']:.3f}", f"{m['p95_ms']:.3f}", f"{m['max_ms']:.2f}", str(m["calls"])
        )
    console.print(modules)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "median_realtime_factor": median_rtf,
                "median_realtime_factor_cpu": median_rtf_cpu,
                "target": TARGET_RTF,
                "runs": rows,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
