"""Controllers in the whole loop: the default campus service with each lateral/longitudinal pair.

Run: python benchmarks/controller_service.py [--minutes 4] [--seeds 0] [--weather clear snow]
         [--pairs heading_pid:watonobus heading_pid:cascaded_pi ...] [--json out.json]

Each pair is selected in the run configuration (``[stack] lateral_controller`` and
``longitudinal_controller``) and run on the loop engine, vehicle safety included; everything else is
the default stack with radar-tracking perception. Reported per run: the referee's takeovers, rule
violations and collisions, stops served (and missed) with their curb gaps, all-way-stop entries out
of arrival order, the peak cross-track error against the stack's planned path (10 Hz, at the point
the path is laid for, boarding excluded), route progress, and the comfort figures as the evaluation
measures them (the shuttle's acceleration averaged over 0.1 s windows; jerk from adjacent windows)
against Snow Lion's measured envelope (-1.83..1.12 m/s^2, |jerk| <= 1.84 m/s^3), outside emergencies
as the evaluation counts them (the emergency-stop state or brake and the 3 s after, with their
count). The reference is the default pair (``heading_pid:watonobus``) in the same run: progress as a
ratio.
One core, BLAS one thread.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import math
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from lastmile.control.lateral import LateralControllerName
from lastmile.control.longitudinal import LongitudinalControllerName
from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.run_events import EventKind
from lastmile.core.vehicle_messages import BehaviourState
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.run_config import RunConfig
from lastmile.sim.scenario import default_service

COMFORT = (-1.83, 1.12, 1.84)
DEFAULT_PAIRS = (
    "heading_pid:watonobus",
    "heading_pid:cascaded_pi",
    "pure_pursuit:cascaded_pi",
    "stanley:cascaded_pi",
    "model_predictive_stanley:cascaded_pi",
    "snow_lion_mpc:cascaded_pi",
    "nus_pure_pursuit:cascaded_pi",
    "gem_waypoint:cascaded_pi",
)


def run(pair: str, seed: int, minutes: float, weather: str) -> dict[str, object]:
    lat, lon = pair.split(":")
    scenario = dataclasses.replace(default_service(seed=seed, weather=weather), minutes=minutes)
    stack = dataclasses.replace(
        RunConfig().stack,
        perception=PerceptionMode.RADAR_TRACKING,
        lateral_controller=LateralControllerName(lat),
        longitudinal_controller=LongitudinalControllerName(lon),
    )
    loop = build_closed_loop(scenario, RunConfig(stack=stack))
    sim = loop.world
    accel, emergency, events, xte = [], [], [], []
    stack = loop.software
    geometry = stack.geometry
    per = round(100_000 / loop.tick_us)
    cpu0 = time.process_time()
    for record in loop.ticks(round(minutes * 60e6 / loop.tick_us)):
        accel.append(sim.ego_state.accel_mps2)
        # Cross-track error against the stack's planned path (the evaluation reads it; the stack never
        # reads truth), at the point the path is laid for: the rear axle at a curb (rear wheels
        # straight), the centre of the wheelbase elsewhere (all-wheel steer).
        path = stack._path
        if record.tick % per == 0 and path is not None and record.state != BehaviourState.ONBOARDING:
            e = sim.ego_state
            at_curb = record.state in (BehaviourState.PULLOVER, BehaviourState.MERGING)
            lead = 0.0 if at_curb or not geometry.all_wheel_steer else geometry.wheelbase_m / 2.0
            x, y = e.x_m + lead * math.cos(e.yaw_rad), e.y_m + lead * math.sin(e.yaw_rad)
            xte.append(abs(path.project(x, y).d_m))
        emergency.append(
            record.verdict.command.emergency_brake or record.state == BehaviourState.EMERGENCY_STOP
        )
        events += record.events
    a = np.asarray(accel)
    k = len(a) // per * per
    # As the evaluation: rows in an emergency stop and the 3 s after it are exempt from comfort.
    e = np.asarray(emergency)
    after = round(3.0e6 / loop.tick_us)
    exempt = np.convolve(e.astype(float), np.ones(after + 1))[: len(e)] > 0.0
    windows = a[:k].reshape(-1, per).mean(axis=1)
    win_exempt = exempt[:k].reshape(-1, per).any(axis=1)
    jerk = np.diff(windows) / 0.1
    jerk_ok = ~(win_exempt[1:] | win_exempt[:-1])
    kept = windows[~win_exempt]
    jerk = jerk[jerk_ok]
    episodes = int(np.count_nonzero(e[1:] & ~e[:-1]) + int(e[0]))
    kinds = collections.Counter(k for _, k, _ in events)
    gaps = [float(d["curb_gap_m"]) for _, k, d in events if k == EventKind.STOP_SERVED]
    return {
        "pair": pair,
        "seed": seed,
        "weather": weather,
        "takeovers": kinds.get("takeover", 0),
        "rule_violations": kinds.get("rule_violation", 0),
        "collisions": kinds.get("collision", 0),
        "stops_served": len(gaps),
        "stops_missed": kinds.get("stop_missed", 0),
        # The arrival order at all-way stops (the evaluation's intersection_entries_out_of_order).
        "out_of_order": sum(
            1 for _, k, d in events if k == EventKind.INTERSECTION_ENTRY and not d["order_ok"]
        ),
        "curb_gap_max_m": max(gaps) if gaps else None,
        "xte_peak_m": max(xte) if xte else None,
        "progress_m": float(sim.route_progress_m),
        "emergency_episodes": episodes,
        "accel_min_mps2": float(kept.min()),
        "accel_max_mps2": float(kept.max()),
        "jerk_min_mps3": float(jerk.min()),
        "jerk_max_mps3": float(jerk.max()),
        "comfort_in_envelope": bool(
            kept.min() >= COMFORT[0] and kept.max() <= COMFORT[1] and np.abs(jerk).max() <= COMFORT[2]
        ),
        "cpu_s": time.process_time() - cpu0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=4.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--weather", nargs="+", default=["clear"])
    ap.add_argument("--pairs", nargs="+", default=list(DEFAULT_PAIRS))
    ap.add_argument(
        "--json", type=Path, default=Path(__file__).with_name("results") / "controller_service.json"
    )
    args = ap.parse_args()
    load_before = os.getloadavg()
    rows = []
    for w in args.weather:
        for s in args.seeds:
            for p in args.pairs:
                rows.append(run(p, s, args.minutes, w))
                r = rows[-1]
                print(
                    f"{p} {w} seed {s}: takeovers {r['takeovers']} violations {r['rule_violations']} "
                    f"collisions {r['collisions']} stops {r['stops_served']} missed {r['stops_missed']} "
                    f"max curb gap {r['curb_gap_max_m']} peak xte {r['xte_peak_m']}",
                    flush=True,
                )
    base = {(r["seed"], r["weather"]): r["progress_m"] for r in rows if r["pair"] == "heading_pid:watonobus"}
    table = Table(title=f"default service, {args.minutes} min per run, radar-tracking perception")
    columns = ("pair", "weather", "seed", "takeovers", "violations", "collisions", "emergencies", "stops")
    columns += ("missed", "out of order")
    columns += ("max curb gap m", "peak xte m")
    columns += ("progress m", "vs default", "accel min..max", "jerk min..max", "comfort", "CPU s")
    for col in columns:
        table.add_column(col, justify="right")
    for r in rows:
        ref = base.get((r["seed"], r["weather"]))
        gap = r["curb_gap_max_m"]
        table.add_row(
            str(r["pair"]), str(r["weather"]), str(r["seed"]), str(r["takeovers"]), str(r["rule_violations"]),
            str(r["collisions"]), str(r["emergency_episodes"]), str(r["stops_served"]),
            str(r["stops_missed"]), str(r["out_of_order"]),
            "-" if gap is None else f"{gap:.2f}",
            "-" if r["xte_peak_m"] is None else f"{r['xte_peak_m']:.2f}",
            f"{r['progress_m']:.0f}", "-" if ref is None else f"{float(r['progress_m']) / ref:.3f}x",
            f"{r['accel_min_mps2']:.2f}..{r['accel_max_mps2']:.2f}",
            f"{r['jerk_min_mps3']:.2f}..{r['jerk_max_mps3']:.2f}",
            "yes" if r["comfort_in_envelope"] else "no", f"{r['cpu_s']:.0f}",
        )  # fmt: skip
    console = Console(width=200)
    console.print(table)
    load_after = os.getloadavg()
    console.print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (2 cores)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"runs": rows, "load_avg": [load_before[0], load_after[0]]}, indent=2))
    console.print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
