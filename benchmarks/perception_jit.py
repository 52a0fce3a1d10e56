"""Perception JIT cost: the first LiDAR pipeline frame of a fresh process, with and without Numba's cache.

Run: python benchmarks/perception_jit.py [--repeats 3] [--json out.json]
The perception kernels (``perception/*_kernel.py``) are compiled by Numba on their first call and
cached on disk (``cache=True``). Each measurement is a fresh Python process (one core, BLAS 1 thread)
that imports the pipeline, then times with ``time.process_time`` its first and second frame of the
synthetic three-LiDAR rig (``perception_speed.py``'s frame). "cold": an empty ``NUMBA_CACHE_DIR``
(every kernel compiled); "warm": the same directory again (kernels loaded from the cache); "fresh
install, warmed": another empty directory, filled by ``python -m lastmile.perception.warmup`` (what
``scripts/bootstrap.sh`` and ``lastmile warmup`` run once per install, on their own synthetic scene),
then a fresh process's first frame. "compiled" counts the kernel signatures Numba had to compile
during the first frame (0: everything came from the cache). The second frame is the steady state the
first is compared with. Medians over repeats.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = """
import json, os, sys, time
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
sys.path.insert(0, %(root)r); sys.path.insert(0, %(bench)r)
t0 = time.process_time()
from lastmile.perception.pipeline import LidarPipeline
t1 = time.process_time()
from perception_speed import _rig_frame
sweeps, ext, traj, curb = _rig_frame(0)
pipe = LidarPipeline()
t2 = time.process_time()
pipe.process(sweeps, ext, traj, None, curb)
t3 = time.process_time()
pipe.process(sweeps, ext, traj, None, curb)
t4 = time.process_time()
from lastmile.perception.warmup import entry_kernels
compiled = sum(len(fn.stats.cache_misses) for fn in entry_kernels().values())
print(json.dumps({"import_ms": (t1 - t0) * 1e3, "first_ms": (t3 - t2) * 1e3, "second_ms": (t4 - t3) * 1e3,
                  "compiled": compiled}))
"""


def _child(cache_dir: str) -> dict[str, float]:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    code = _CHILD % {"root": str(ROOT), "bench": str(ROOT / "benchmarks")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def _warmup(cache_dir: str) -> float:
    """Runs the install-time warm-up into ``cache_dir``; returns its wall seconds."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "lastmile.perception.warmup"], env=env, capture_output=True, check=True
    )
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "perception_jit.json")
    args = parser.parse_args()
    runs: dict[str, list[dict[str, float]]] = {"cold": [], "warm": [], "fresh install, warmed": []}
    warmup_s = []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="numba_cache_") as d:
            runs["cold"].append(_child(d))
            runs["warm"].append(_child(d))
        with tempfile.TemporaryDirectory(prefix="numba_cache_") as d:
            warmup_s.append(_warmup(d))
            runs["fresh install, warmed"].append(_child(d))
    keys = ("import_ms", "first_ms", "second_ms", "compiled")
    rows = {name: {k: statistics.median(r[k] for r in rs) for k in keys} for name, rs in runs.items()}
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"Perception pipeline in a fresh process, CPU ms (median of {args.repeats})")
    for col in ("cache", "import", "first frame", "second frame", "first / second", "compiled"):
        t.add_column(col, justify="right")
    for name, r in rows.items():
        t.add_row(
            name,
            f"{r['import_ms']:.0f}",
            f"{r['first_ms']:.0f}",
            f"{r['second_ms']:.1f}",
            f"{r['first_ms'] / r['second_ms']:.0f}x",
            f"{r['compiled']:.0f}",
        )
    console = Console(width=120)
    console.print(t)
    console.print(
        f"install-time warm-up (python -m lastmile.perception.warmup, wall): median "
        f"{statistics.median(warmup_s):.1f} s; machine load average {os.getloadavg()[0]:.1f}"
    )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "repeats": args.repeats,
                "median": rows,
                "runs": runs,
                "warmup_s": warmup_s,
                "load_average": os.getloadavg()[0],
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
