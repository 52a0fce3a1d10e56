"""aUToTrack in simulation: radar frames delivered in and out of capture order, per weather.

Run: python benchmarks/tracking_sim.py [--seconds 60] [--seeds 0 1] [--sensors radar radar+lidar]
         [--json out.json]

The scene (``tests/tracking/sim_scene.py``): the shuttle stands before a crosswalk, cars pass both ways
and queue behind it, pedestrians cross; four radars stamp frames at 20, 16.7, 14.3 and 12.5 Hz, each
frame arriving after a random latency of up to 300 ms. Per weather (clear/rain/snow/fog) and arrival
order, the tracker (rollback on) is fed the frames as they are handed over; every 100 ms the tracks it
publishes for that instant are matched to the simulator's ground truth within 50 m (Hungarian, 3 m gate):
ID switches, matches, misses, false tracks, position error (RMSE/median/p95). Orders:

- ``ordered``: frames handed over in capture order (a reorder buffer waits for every earlier frame);
- ``shuffled``: frames handed over on arrival, out of capture order; rollback replays the late ones;
- baseline ``drop late``: shuffled, without rollback: a frame older than the newest processed is dropped
  (what a tracker without a message queue does). Ratios are baseline / rollback.

Sensor sets: ``radar`` (the four radars) and ``radar+lidar`` (plus the three simulated LiDARs through
``perception.LidarPipeline`` on ``RawSensorRig`` frames, clusters as a fifth source of class UNKNOWN;
fusion happens in the tracker). Static clusters (poles, walls, hedges) are tracked too and count as
false tracks, since the ground truth lists agents only.

A third table explains the shuffled runs' ID switches that the ordered runs do not have (each paired
with an ordered switch of the same object within 1 s, or else given a cause) from the track hypotheses
and the published-id hand-overs recorded by ``tests/tracking/sim_id_switches.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from collections import Counter
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the simulated scene lives beside the tests that use it

from tests.tracking import sim_id_switches, sim_scene  # noqa: E402

WEATHERS = ("clear", "rain", "snow", "fog")
MODES = (("ordered", True), ("shuffled", True), ("shuffled", False))


def _label(order: str, rollback: bool) -> str:
    return f"{order}" if rollback else f"{order}, drop late (no rollback)"


def run(seconds: float, seeds: list[int], lidar: bool) -> tuple[dict, dict[str, bool]]:
    """Totals over the seeds, per weather and mode; per weather, whether the final states were identical."""
    out: dict = {}
    same: dict[str, bool] = {}
    for weather in WEATHERS:
        out[weather] = {}
        per_mode: dict[str, list] = {_label(o, r): [] for o, r in MODES}
        identical: list[bool] = []
        extra: Counter[str] = Counter()
        not_in_shuffled = 0
        for seed in seeds:
            rec = sim_scene.record(seed, seconds, weather, lidar=lidar)
            observers: dict[str, sim_id_switches.IdObserver] = {}
            for order, rollback in MODES:
                obs = sim_id_switches.IdObserver() if rollback else None
                if obs is not None:
                    observers[order] = obs
                res = sim_scene.feed(
                    rec, sim_scene.deliveries(rec, order, seed), rollback=rollback, observer=obs
                )
                per_mode[_label(order, rollback)].append((sim_scene.score(rec, res), res))
            # Each ID switch of the shuffled run that the ordered run does not have, by cause.
            causes, avoided = sim_id_switches.explain(
                rec,
                per_mode["ordered"][-1][1],
                observers["ordered"],
                per_mode["shuffled"][-1][1],
                observers["shuffled"],
            )
            extra.update(causes)
            not_in_shuffled += avoided
            # Once every frame is in, rollback must leave exactly the state in-order delivery leaves.
            a, b = (per_mode[_label(o, True)][-1][1].final for o in ("ordered", "shuffled"))
            assert a is not None and b is not None
            identical.append(
                bool(np.array_equal(a.table, b.table) and np.array_equal(a.class_prob, b.class_prob))
            )
        for label, runs in per_mode.items():
            scores = [s for s, _ in runs]
            results = [r for _, r in runs]
            matches = sum(s.matches for s in scores)
            out[weather][label] = {
                "id_switches": sum(s.id_switches for s in scores),
                "matches": matches,
                "misses": sum(s.misses for s in scores),
                "false_tracks": sum(s.false_tracks for s in scores),
                # Over seeds: RMSE pooled by matches; median and p95 as the median of the seeds' values.
                "rmse_m": (sum(s.rmse_m**2 * s.matches for s in scores) / matches) ** 0.5
                if matches
                else None,
                "median_m": statistics.median(s.median_m for s in scores),
                "p95_m": statistics.median(s.p95_m for s in scores),
                "frames_fed": sum(r.fed for r in results),
                "frames_dropped": sum(r.dropped for r in results),
                "rollbacks": sum(r.rollbacks for r in results),
                "ids_inherited": sum(r.inherited for r in results),
                "tracker_cpu_s": sum(r.seconds for r in results),
            }
        out[weather]["extra_switches"] = {
            "causes": {c: extra[c] for c in sim_id_switches.CAUSES},
            "total": sum(extra.values()),
            "ordered_switches_not_in_shuffled": not_in_shuffled,
        }
        same[weather] = all(identical)
    return out, same


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per run")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument(
        "--sensors", nargs="+", choices=("radar", "radar+lidar"), default=["radar", "radar+lidar"]
    )
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "tracking_sim.json")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    console = Console(width=170)  # wide tables stay readable when piped to a file
    runs = {sensors: run(args.seconds, args.seeds, sensors == "radar+lidar") for sensors in args.sensors}
    report = {sensors: r[0] for sensors, r in runs.items()}
    identical = {sensors: r[1] for sensors, r in runs.items()}
    table = Table(
        title=f"aUToTrack in simulation, {args.seconds:.0f} s x seeds {args.seeds}, scored every 100 ms"
    )
    table.add_column("sensors")
    for col in (
        "weather",
        "order",
        "IDS",
        "matches",
        "misses",
        "false",
        "RMSE m",
        "median m",
        "p95 m",
        "fed/dropped",
        "ids kept",
    ):
        table.add_column(col, justify="right")
    for sensors, by_weather in report.items():
        for weather, modes in by_weather.items():
            for label, m in modes.items():
                if label == "extra_switches":
                    continue
                table.add_row(
                    sensors,
                    weather,
                    label,
                    str(m["id_switches"]),
                    str(m["matches"]),
                    str(m["misses"]),
                    str(m["false_tracks"]),
                    f"{m['rmse_m']:.3f}",
                    f"{m['median_m']:.3f}",
                    f"{m['p95_m']:.3f}",
                    f"{m['frames_fed']}/{m['frames_dropped']}",
                    str(m["ids_inherited"]),
                )
    console.print(table)
    ratios = Table(
        title="Shuffled arrival: rollback vs ordered, and the drop-late baseline vs rollback (ratios)"
    )
    ratios.add_column("sensors")
    for col in (
        "weather",
        "matches shuf/ord",
        "IDS shuf/ord",
        "RMSE shuf/ord",
        "median shuf/ord",
        "matches drop/rb",
        "IDS drop/rb",
        "median drop/rb",
        "final state shuf == ord",
    ):
        ratios.add_column(col, justify="right")
    drop = _label("shuffled", False)

    def ratio(a: float, b: float) -> str:
        return f"{a / b:.3f}" if b else "n/a"

    for sensors, by_weather in report.items():
        for weather, modes in by_weather.items():
            o, s, d = modes["ordered"], modes["shuffled"], modes[drop]
            ratios.add_row(
                sensors,
                weather,
                ratio(s["matches"], o["matches"]),
                ratio(s["id_switches"], o["id_switches"]),
                ratio(s["rmse_m"], o["rmse_m"]),
                ratio(s["median_m"], o["median_m"]),
                ratio(d["matches"], s["matches"]),
                ratio(d["id_switches"], s["id_switches"]),
                ratio(d["median_m"], s["median_m"]),
                "identical" if identical[sensors][weather] else "DIFFERENT",
            )
    console.print(ratios)
    causes = Table(
        title="ID switches of shuffled runs that ordered runs do not have (paired per object within "
        f"{sim_id_switches.PAIR_WINDOW_US / 1e6:.0f} s), by cause"
    )
    for col in ("sensors", "weather", "extra", "ordered-only", *sim_id_switches.CAUSES):
        causes.add_column(col, justify="right")
    for sensors, by_weather in report.items():
        for weather, modes in by_weather.items():
            x = modes["extra_switches"]
            causes.add_row(
                sensors,
                weather,
                str(x["total"]),
                str(x["ordered_switches_not_in_shuffled"]),
                *(str(x["causes"][c]) for c in sim_id_switches.CAUSES),
            )
    console.print(causes)
    for name, text in sim_id_switches.CAUSES.items():
        console.print(f"  {name}: {text}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "seconds": args.seconds,
                "seeds": args.seeds,
                "results": report,
                "final_state_identical": identical,
            },
            indent=2,
        )
    )
    console.print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
