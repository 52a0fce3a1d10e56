"""Phantom tracks: raw-sensor driving on a route map with nobody on it, counting what is published anyway.

Run: python benchmarks/phantom_tracks.py [--route examples/routes/bits_campus_loop.toml] [--seconds 60]
    [--start-s 50] [--json out.json]
The default run configuration (raw LiDAR, camera and radar) drives the route's service from route s
``--start-s`` for ``--seconds`` with no road users and no riders (``Scenario`` with the route's map
only). Every planning cycle (10 Hz) the stack's published tracks are counted (there is nothing to
track: each one is an artefact) and decision's stop reason and the shuttle's true speed recorded.
Printed: the share of cycles with a published track, the most at once, the stop reasons, the speed
range after the first 5 s, and the CPU time per simulated second beside a reference operation (a
SciPy ``cKDTree`` build over 100k random points plus one radius query).

The BITS loop is a real Autoware-format Lanelet2 map with one lanelet and no mapped curbs: the
simulator raises everything beside the lane 0.15 m, and the stack has no curb line to explain it.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]

from lastmile.runner.closed_loop import DEFAULT_CONFIG, build_closed_loop  # noqa: E402
from lastmile.sim.passengers import PassengerConfig  # noqa: E402
from lastmile.sim.scenario import route_service  # noqa: E402


def _reference_ms() -> float:
    pts = np.random.default_rng(0).uniform(-50.0, 50.0, (100_000, 3))
    t0 = time.process_time()
    cKDTree(pts).query_ball_point(pts[0], 0.5)
    return (time.process_time() - t0) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--route", default=str(ROOT / "examples" / "routes" / "bits_campus_loop.toml"))
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--start-s", type=float, default=50.0)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "phantom_tracks.json")
    args = parser.parse_args()
    scenario = dataclasses.replace(
        route_service(args.route, seed=0, minutes=args.seconds / 60.0),
        passengers=PassengerConfig(arrivals_per_stop_per_min=0.0),
        start_route_s_m=args.start_s,
        map_cars=(),  # nobody on the route: every published track is a phantom
        route_crosswalk_pedestrians=None,
    )
    loop = build_closed_loop(scenario, DEFAULT_CONFIG)
    stack = loop.software
    published, speeds = [], []
    reasons: collections.Counter[str] = collections.Counter()
    t0 = time.process_time()
    for record in loop.ticks(round(args.seconds * 1e6 / loop.tick_us)):
        decision = record.output.decision if record.output is not None else None
        if decision is not None and record.tick % 10 == 0:
            published.append(len(stack._tracks))  # the published tracks, as decision got them
            reasons[decision.stop_reason.name] += 1
            speeds.append(loop.world.world.ego.state.speed_mps)
    cpu_s = time.process_time() - t0
    pub, v = np.array(published), np.array(speeds)
    ref = float(np.median([_reference_ms() for _ in range(5)]))
    out = {
        "route": args.route,
        "seconds": args.seconds,
        "start_s_m": args.start_s,
        "planning_cycles": len(pub),
        "share_with_published_track": float(np.mean(pub > 0)),
        "max_published": int(pub.max(initial=0)),
        "stop_reasons": dict(reasons),
        "speed_after_5s_min_mps": float(v[50:].min(initial=np.inf)),
        "speed_max_mps": float(v.max(initial=0.0)),
        "cpu_s_per_sim_s": cpu_s / args.seconds,
        "reference_ms": ref,
        "load_average": os.getloadavg()[0],
    }
    print(
        f"{Path(args.route).name}, {args.seconds:.0f} s from route s {args.start_s:g} m, no road users: "
        f"{out['planning_cycles']} planning cycles, {out['share_with_published_track']:.0%} with a published "
        f"track, at most {out['max_published']} at once; stop reasons {out['stop_reasons']}; speed after 5 s "
        f"{out['speed_after_5s_min_mps']:.2f}-{out['speed_max_mps']:.2f} m/s"
    )
    print(
        f"CPU {out['cpu_s_per_sim_s']:.2f} s per simulated second; reference (cKDTree build over 100k "
        f"points + one radius query) {ref:.1f} ms; load average {out['load_average']:.1f}"
    )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    sys.exit(main())
