"""GEM's sign detector per rig frame: the stack's corridor-first call against GEM's stages on the whole frame.

Run: python benchmarks/sign_detector_cost.py [--seconds 20] [--repeats 5] [--json out.json]

Frames: the simulator's own three-LiDAR rig on the campus, the shuttle driving from route s 292 towards
the all-way stop's eastbound plate (raw perception, ``[stack.gem_sign_stop]`` on), clear and snow; each
rig frame the stack handed the option (base frame, weather noise left out, with its pose estimate) is
kept and timed afterwards. Per frame, thread-CPU medians over ``--repeats``:

- ``ours``: :meth:`lastmile.stack.gem_sign_stop.GemSignStop.update` (the route corridor, then GEM's five
  stages on what is left), on a fresh instance each time;
- ``gem``: :func:`lastmile.perception.signs.detect_sign` on the whole frame, as GEM runs it (its stage 1:
  ahead, +/- 10 m) -- what a user without the corridor would run;
- ``ref``: the reference operation the perception benchmarks use, SciPy's ``cKDTree`` built over the
  frame's points plus one 0.5 m radius query of them all (``query_ball_point``).

It prints the medians, the ratios to the reference, and how often each finds a plate and which (the
nearest mapped plate within 2 m, else ``unmapped``); the machine's load average before and after.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.spatial import cKDTree

from lastmile.core.vehicle_messages import LocalizationEstimate
from lastmile.perception.signs import detect_sign
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.run_config import RunConfig
from lastmile.sim.scenario import Scenario
from lastmile.stack.gem_sign_stop import GemSignStop, GemSignStopSettings
from lastmile.stack.shuttle_stack import ShuttleStack

ROOT = Path(__file__).resolve().parents[1]
START_S_M = 292.0

Frame = tuple[np.ndarray, LocalizationEstimate, float | None]


def _frames(weather: str, seconds: float) -> tuple[list[Frame], ShuttleStack]:
    base = RunConfig()
    config = dataclasses.replace(
        base, stack=dataclasses.replace(base.stack, gem_sign_stop=GemSignStopSettings())
    )
    scenario = Scenario(name="sign_cost", minutes=seconds / 60.0, start_route_s_m=START_S_M, weather=weather)
    loop = build_closed_loop(scenario, config)
    stack = loop.software
    assert isinstance(stack, ShuttleStack) and stack.sign_stop is not None
    frames: list[Frame] = []
    update = stack.sign_stop.update

    def record(xyzi: np.ndarray, estimate: LocalizationEstimate, rear_s_m: float | None) -> None:
        frames.append((np.array(xyzi), estimate, rear_s_m))
        update(xyzi, estimate, rear_s_m)

    stack.sign_stop.update = record  # type: ignore[method-assign]
    for rec in loop.ticks(round(seconds * 1e6 / loop.tick_us)):
        assert rec.output is not None, rec.failure
    return [f for f in frames if f[1].valid and f[2] is not None], stack


def _cpu_ms(fn: object, repeats: int) -> float:
    out = []
    for _ in range(repeats):
        t0 = time.thread_time()
        fn()  # type: ignore[operator]
        out.append((time.thread_time() - t0) * 1e3)
    return statistics.median(out)


def _which(stop: GemSignStop, xy: np.ndarray) -> str:
    key, _ = stop._mapped(xy, 0.0)
    return key


def _measure(weather: str, seconds: float, repeats: int) -> dict[str, object]:
    frames, stack = _frames(weather, seconds)
    layers, front_m = stack.layers, stack.geometry.front_from_rear_axle_m
    rule = stack.config.decision.traffic_lights
    settings = GemSignStopSettings()
    ours_ms, gem_ms, ref_ms = [], [], []
    found: dict[str, dict[str, int]] = {"ours": {}, "gem": {}}
    for xyzi, est, rear_s in frames:

        def ours(
            xyzi: np.ndarray = xyzi, est: LocalizationEstimate = est, rear_s: float | None = rear_s
        ) -> GemSignStop:
            stop = GemSignStop(settings, layers, front_m, rule)
            stop.update(xyzi, est, rear_s)
            return stop

        def gem(xyzi: np.ndarray = xyzi) -> object:
            return detect_sign(xyzi[:, :3], xyzi[:, 3], np.random.default_rng(0), settings.detector)

        def ref(pts: np.ndarray = xyzi[:, :3]) -> None:
            cKDTree(pts).query_ball_point(pts, 0.5, return_length=True)

        ours_ms.append(_cpu_ms(ours, repeats))
        gem_ms.append(_cpu_ms(gem, repeats))
        ref_ms.append(_cpu_ms(ref, repeats))
        fresh = ours()
        for key in fresh.stats.per_sign:
            found["ours"][key] = found["ours"].get(key, 0) + 1
        det = detect_sign(xyzi[:, :3], xyzi[:, 3], np.random.default_rng(0), settings.detector)
        if det is not None:
            xy = est.map_from_base.apply_points(det.centroid_m[:2].reshape(1, 2))[0]
            key = _which(fresh, xy)
            found["gem"][key] = found["gem"].get(key, 0) + 1
    return {
        "weather": weather,
        "frames": len(frames),
        "points_median": statistics.median(len(f[0]) for f in frames),
        "ours_ms": statistics.median(ours_ms),
        "gem_ms": statistics.median(gem_ms),
        "ref_ms": statistics.median(ref_ms),
        "ours_p95_ms": float(np.percentile(ours_ms, 95)),
        "gem_p95_ms": float(np.percentile(gem_ms, 95)),
        "found": found,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--json", type=Path, default=ROOT / "benchmarks" / "results" / "sign_detector_cost.json"
    )
    args = parser.parse_args()
    load_before = os.getloadavg()
    rows = [_measure(w, args.seconds, args.repeats) for w in ("clear", "snow")]
    load_after = os.getloadavg()
    table = Table(title="GEM's sign detector, thread-CPU ms per rig frame (medians)")
    for col in (
        "weather",
        "frames",
        "points",
        "ours",
        "gem (whole frame)",
        "ref (cKDTree+query)",
        "ours / ref",
        "gem / ref",
        "ours found",
        "gem found",
    ):
        table.add_column(col)
    for r in rows:
        table.add_row(
            str(r["weather"]),
            str(r["frames"]),
            f"{r['points_median']:.0f}",
            f"{r['ours_ms']:.2f} (p95 {r['ours_p95_ms']:.2f})",
            f"{r['gem_ms']:.2f} (p95 {r['gem_p95_ms']:.2f})",
            f"{r['ref_ms']:.2f}",
            f"{r['ours_ms'] / r['ref_ms']:.2f}",
            f"{r['gem_ms'] / r['ref_ms']:.2f}",
            str(r["found"]["ours"]),
            str(r["found"]["gem"]),  # type: ignore[index]
        )
    console = Console(width=200)
    console.print(table)
    console.print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (2 cores, shared)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps({"rows": rows, "load_before": load_before, "load_after": load_after}, indent=1)
    )
    console.print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
