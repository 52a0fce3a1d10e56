"""Real-time factor of the service on user route maps against the campus map, in one run.

Run: python benchmarks/route_realtime.py [--minutes 2] [--repeats 3] [--perception radar|lidar]
         [--json benchmarks/results/route_realtime.json]

The same scenario on every map: riders arriving at the stops (0.3 per stop per minute), no other
traffic, seed 0, so that the ratio measures what the map costs (its size, its lanelets, the route's
stops and lane changes), not the campus's extra road users. Issue #18 asks for the route maps within
20 % of the campus map (ratio >= 0.8). Medians over the repeats; the machine load (1-minute load
average) is printed beside every figure, and a fixed reference operation (1,000 numpy 64 x 64 matrix
products) is timed at each repeat so figures from a loaded machine can be read against it. Maps in
../shared/data that are absent are skipped with a line saying so. BLAS is pinned to one thread.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from rich.console import Console
from rich.table import Table

from lastmile.core.perception_mode import PerceptionMode
from lastmile.runner.closed_loop import run_scenario
from lastmile.runner.run_config import RunConfig
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import Scenario, route_service
from reference_ops import matrix_products_ms

ROOT = Path(__file__).resolve().parents[1]
ROUTES = {
    "BITS campus loop": ROOT / "examples" / "routes" / "bits_campus_loop.toml",
    "Lanelet2 example roundabout": ROOT / "examples" / "routes" / "lanelet2_example_roundabout.toml",
}
IN_REPO_ROUTES = {"example town block": ROOT / "examples" / "routes" / "town_block_loop.toml"}
TARGET_RATIO = 0.8


def _scenario(route: Path | None, minutes: float) -> Scenario:
    riders = PassengerConfig(arrivals_per_stop_per_min=0.3)
    if route is None:
        return Scenario(name="campus_riders", minutes=minutes, seed=0, passengers=riders)
    # The route service's own traffic and pedestrians are left out: the campus scenario has none.
    return dataclasses.replace(
        route_service(str(route), minutes=minutes),
        passengers=riders,
        map_cars=(),
        route_crosswalk_pedestrians=None,
    )


def _measure(route: Path | None, minutes: float, config: RunConfig) -> dict[str, float]:
    load = os.getloadavg()[0]
    reference = matrix_products_ms()
    log = run_scenario(_scenario(route, minutes), config)
    return {
        "realtime_factor": float(log.timing["realtime_factor"]),
        "realtime_factor_cpu": float(log.timing["realtime_factor_cpu"]),
        "load_1min": load,
        "reference_ms": reference,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=2.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--perception", choices=("radar", "lidar"), default="radar")
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/route_realtime.json"))
    args = parser.parse_args()
    os.chdir(ROOT)  # the route files name their maps from the repository root
    mode = PerceptionMode.RADAR_TRACKING if args.perception == "radar" else PerceptionMode.LIDAR_CAMERA_RADAR
    config = RunConfig().with_perception(mode)
    maps: dict[str, Path | None] = {"campus (built in)": None}
    console = Console()
    for name, path in ROUTES.items():
        if path.is_file() and (ROOT.parent / "shared" / "data" / "maps").is_dir():
            maps[name] = path
        else:
            console.print(f"skipped {name}: ../shared/data is absent")
    maps.update(IN_REPO_ROUTES)
    runs: dict[str, list[dict[str, float]]] = {name: [] for name in maps}
    for _ in range(args.repeats):  # interleaved, so a load change hits every map alike
        for name, path in maps.items():
            runs[name].append(_measure(path, args.minutes, config))
    med = {
        name: {key: statistics.median(r[key] for r in rows) for key in rows[0]} for name, rows in runs.items()
    }
    campus = med["campus (built in)"]
    ratios = {n: m["realtime_factor_cpu"] / campus["realtime_factor_cpu"] for n, m in med.items()}
    table = Table(
        title=f"real-time factor, {args.minutes:g} simulated min, {args.perception} perception, "
        f"median of {args.repeats}"
    )
    for col in ("map", "RTF (wall)", "RTF (CPU)", "vs campus (wall)", "vs campus (CPU)", "load", "ref ms"):
        table.add_column(col, justify="right")
    for name, m in med.items():
        table.add_row(
            name,
            f"{m['realtime_factor']:.2f}",
            f"{m['realtime_factor_cpu']:.2f}",
            f"{m['realtime_factor'] / campus['realtime_factor']:.2f}",
            f"{ratios[name]:.2f}",
            f"{m['load_1min']:.1f}",
            f"{m['reference_ms']:.1f}",
        )
    console.print(table)
    console.print(f"target: every route map's CPU ratio >= {TARGET_RATIO} (within 20 % of the campus)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "minutes": args.minutes,
                "perception": args.perception,
                "target_ratio": TARGET_RATIO,
                "medians": med,
                "ratios_cpu": ratios,
                "runs": runs,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
