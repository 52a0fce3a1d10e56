"""Snow Lion's speed planner (s-t search + OSQP piecewise-jerk QP): CPU time per plan and profile quality.

Run: python benchmarks/speed_planner.py [--repeats 50] [--json out.json]

Scenes on an 80 m path with a 20 km/h route limit and a curve (radius 15 m from 30 to 45 m): free road
from rest, a pedestrian crossing 20 m ahead for 5 s, a slower lead vehicle (2 m/s, 15 m ahead), a stop
point at 25 m, and all three obstacles at once at 5 m/s. Reported per scene: CPU time per plan
(median, p95; the search and the QP apart), whether the QP solved, the profile's acceleration and
jerk extremes (Snow Lion's measured envelope: -1.83..1.12 m/s^2, |jerk| <= 1.84 m/s^3). What a user
would otherwise write: a fresh ``osqp.OSQP().setup`` for every plan (same matrices): its QP time as a
ratio. The reference operation: one ``numpy.linalg.solve`` of a dense 123 x 123 system (the QP's
variable count). The planning budget of issue 20 is 20 ms p95 per cycle for the whole planner.
One core, BLAS one thread; thread CPU time (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import osqp
from rich.console import Console
from rich.table import Table

from lastmile.planning.speed_limits import combined_speed_limit_mps
from lastmile.planning.st_speed import StObstacle, StSpeedPlanner, st_search

S = np.arange(0.0, 80.0, 0.5)
KAPPA = np.where((S >= 30.0) & (S <= 45.0), 1.0 / 15.0, 0.0)
T = np.linspace(0.0, 8.0, 17)
PED = StObstacle(t_s=np.array([0.0, 5.0]), s_lo_m=np.array([20.0, 20.0]), s_hi_m=np.array([21.0, 21.0]))
LEAD = StObstacle(t_s=T, s_lo_m=15.0 + 2.0 * T, s_hi_m=19.5 + 2.0 * T)
LATE = StObstacle(t_s=np.array([6.0, 8.0]), s_lo_m=np.array([60.0, 60.0]), s_hi_m=np.array([61.0, 61.0]))


def scenes() -> dict[str, tuple[np.ndarray, float, list[StObstacle]]]:
    free = combined_speed_limit_mps(S, KAPPA, 20.0 / 3.6, 1.0)
    stop = combined_speed_limit_mps(S, KAPPA, 20.0 / 3.6, 1.0, stop_s_m=25.0, max_decel_mps2=1.2)
    return {
        "free_from_rest": (free, 0.0, []),
        "pedestrian_crossing": (free, 4.0, [PED]),
        "slower_lead": (free, 5.0, [LEAD]),
        "stop_point": (stop, 5.0, []),
        "three_obstacles": (free, 5.0, [PED, LEAD, LATE]),
    }


def fresh_qp_ns(planner: StSpeedPlanner) -> int:
    """A fresh OSQP setup and solve of the QP the planner has just solved."""
    cache = planner._solver._derivative_cache  # type: ignore[union-attr]
    c = planner.config
    t0 = time.thread_time_ns()
    solver = osqp.OSQP()
    solver.setup(
        cache["P"], cache["q"], cache["A"], cache["l"], cache["u"], eps_abs=c.eps, eps_rel=c.eps,
        max_iter=c.max_iter, polishing=True, verbose=False,
    )  # fmt: skip
    solver.solve(raise_error=False)
    return time.thread_time_ns() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--json", type=Path, default=Path(__file__).with_name("results") / "speed_planner.json")
    args = ap.parse_args()
    load_before = os.getloadavg()
    rng = np.random.default_rng(0)
    m = rng.standard_normal((123, 123)) + 123 * np.eye(123)
    b = rng.standard_normal(123)
    ref_ns = []
    for _ in range(200):
        t0 = time.thread_time_ns()
        np.linalg.solve(m, b)
        ref_ns.append(time.thread_time_ns() - t0)
    ref_us = statistics.median(ref_ns) / 1e3
    planner = StSpeedPlanner()
    planner.plan(S, combined_speed_limit_mps(S, KAPPA, 5.0, 1.0), 1.0, 0.0)  # set the workspace up
    rows: dict[str, dict[str, float]] = {}
    for name, (limit, v0, obstacles) in scenes().items():
        total, search, fresh = [], [], []
        plan = None
        for _ in range(args.repeats):
            t0 = time.thread_time_ns()
            st_search(S, np.minimum(limit, planner.config.max_speed_mps), v0, obstacles, planner.config)
            t1 = time.thread_time_ns()
            plan = planner.plan(S, limit, v0, 0.0, obstacles)
            t2 = time.thread_time_ns()
            search.append(t1 - t0)
            total.append(t2 - t1)
            fresh.append(fresh_qp_ns(planner))
        assert plan is not None
        qp = [t - s for t, s in zip(total, search, strict=True)]
        rows[name] = {
            "plan_p50_ms": statistics.median(total) / 1e6,
            "plan_p95_ms": float(np.percentile(total, 95)) / 1e6,
            "search_p50_ms": statistics.median(search) / 1e6,
            "qp_p50_ms": statistics.median(qp) / 1e6,
            "fresh_qp_p50_ms": statistics.median(fresh) / 1e6,
            "fresh_over_cached_qp": statistics.median(fresh) / max(statistics.median(qp), 1),
            "solved": float(plan.solved),
            "accel_min_mps2": float(plan.a_mps2.min()),
            "accel_max_mps2": float(plan.a_mps2.max()),
            "jerk_abs_max_mps3": float(np.abs(plan.jerk_mps3).max()),
        }
    table = Table(
        title=f"speed planner, {args.repeats} plans per scene; reference: dense 123x123 solve {ref_us:.0f} us"
    )
    for col in ("scene", "plan p50 ms", "plan p95 ms", "search p50", "QP p50", "fresh QP p50", "fresh/cached",
                "solved", "a min", "a max", "|jerk| max"):  # fmt: skip
        table.add_column(col, justify="right")
    for name, r in rows.items():
        table.add_row(
            name, f"{r['plan_p50_ms']:.2f}", f"{r['plan_p95_ms']:.2f}", f"{r['search_p50_ms']:.2f}",
            f"{r['qp_p50_ms']:.2f}", f"{r['fresh_qp_p50_ms']:.2f}", f"{r['fresh_over_cached_qp']:.2f}x",
            "yes" if r["solved"] else "NO", f"{r['accel_min_mps2']:.2f}", f"{r['accel_max_mps2']:.2f}",
            f"{r['jerk_abs_max_mps3']:.2f}",
        )  # fmt: skip
    console = Console(width=160)
    console.print(table)
    load_after = os.getloadavg()
    console.print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (2 cores)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {"scenes": rows, "reference_solve_us": ref_us, "load_avg": [load_before[0], load_after[0]]},
            indent=2,
        )
    )
    console.print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
