"""Pedestrian cluster splitting on the real KITTI object frames: every labelled object before and after.

Run: python benchmarks/cluster_split_kitti.py [--repeats 5] [--json out.json]
One core (BLAS 1 thread). Per KITTI frame in ../shared/data/kitti_object (velodyne 1.73 m up, so the
flat road is z = 0): adaptive-grid ground, Euclidean clustering at 0.5 m (the pipeline's), then
``cluster_split.split_pedestrians`` (``ClusterSplitConfig(enabled=True)``). For each labelled object
within 45 m: its box's points (above the box bottom + 0.15 m), how many of them the best cluster
holds and that cluster's size and purity (share of its points inside the box), before and after.
Then the parts carved out that no label holds (KITTI labels only what the front camera sees), and
the split's CPU time beside a reference on the same frame: SciPy's ``cKDTree`` build plus one
0.5 m radius query (median of ``--repeats``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.perception.kitti import VELODYNE_HEIGHT_M, frame_names, load_frame  # noqa: E402

from lastmile.perception.cluster_split import ClusterSplitConfig, split_pedestrians  # noqa: E402
from lastmile.perception.clustering import euclidean_cluster_labels  # noqa: E402
from lastmile.perception.ground import make_ground_segmenter  # noqa: E402

RANGE_M = 45.0


def _best(labels: np.ndarray, inside: np.ndarray) -> tuple[int, int, float]:
    """(box points in the best cluster, that cluster's size, its purity)."""
    obj = labels[inside]
    obj = obj[obj >= 0]
    if len(obj) == 0:
        return 0, 0, 0.0
    k = int(np.bincount(obj).argmax())
    members = labels == k
    return (
        int(np.count_nonzero(obj == k)),
        int(members.sum()),
        float((members & inside).sum() / members.sum()),
    )


def _median_ms(fn: object, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()  # type: ignore[operator]
        times.append((time.process_time() - t0) * 1e3)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--json", type=Path, default=ROOT / "benchmarks" / "results" / "cluster_split_kitti.json"
    )
    args = parser.parse_args()
    names = frame_names()
    if not names:
        sys.exit("KITTI object frames not found at <repo>/../shared/data/kitti_object")
    config = ClusterSplitConfig(enabled=True)
    rows, frames = [], []
    for name in names:
        frame = load_frame(name)
        xyz = frame.velo[:, :3].astype(np.float64) + np.array([0.0, 0.0, VELODYNE_HEIGHT_M])
        ground = make_ground_segmenter("adaptive_grid").segment(xyz)
        ng = np.flatnonzero(~ground)
        before = np.full(len(xyz), -1, dtype=np.int64)
        before[ng] = euclidean_cluster_labels(xyz[ng], 0.5)
        after = split_pedestrians(xyz, before, ground, config)
        labelled = np.zeros(len(xyz), dtype=bool)
        for lab in frame.labels:
            centre = frame.centre_velo(lab)
            if np.hypot(centre[0], centre[1]) > RANGE_M:
                continue
            inside = frame.in_box(lab, frame.velo[:, :3].astype(np.float64), bottom_margin_m=0.15)
            labelled |= inside
            b, a = _best(before, inside), _best(after, inside)
            rows.append(
                {
                    "frame": name,
                    "kind": lab.kind,
                    "range_m": float(np.hypot(centre[0], centre[1])),
                    "box_points": int(inside.sum()),
                    "before": b,
                    "after": a,
                }
            )
        new = np.unique(after[after > before.max()])
        unlabelled = sum(1 for k in new.tolist() if not labelled[after == k].any())
        split_ms = _median_ms(lambda: split_pedestrians(xyz, before, ground, config), args.repeats)  # noqa: B023
        ref_ms = _median_ms(lambda: cKDTree(xyz).query_ball_point(xyz[0], 0.5), args.repeats)  # noqa: B023
        frames.append(
            {
                "frame": name,
                "parts": len(new),
                "unlabelled_parts": unlabelled,
                "split_ms": split_ms,
                "ref_ms": ref_ms,
            }
        )
    console = Console(width=160)
    t = Table(
        title="Labelled objects within 45 m: best cluster before / after (box points held, size, purity)"
    )
    for col in ("frame", "object", "range m", "box points", "before", "after"):
        t.add_column(col, justify="right")
    for r in rows:
        b, a = r["before"], r["after"]
        t.add_row(
            str(r["frame"]),
            str(r["kind"]),
            f"{r['range_m']:.1f}",
            str(r["box_points"]),
            f"{b[0]} / {b[1]} / {b[2]:.2f}",  # type: ignore[index]
            f"{a[0]} / {a[1]} / {a[2]:.2f}",  # type: ignore[index]
        )
    console.print(t)
    f = Table(title=f"Parts carved out per frame, and the split's CPU time (median of {args.repeats})")
    for col in ("frame", "parts", "in no label", "split ms", "ref ms (cKDTree build + query)", "ratio"):
        f.add_column(col, justify="right")
    for r in frames:
        f.add_row(
            str(r["frame"]),
            str(r["parts"]),
            str(r["unlabelled_parts"]),
            f"{r['split_ms']:.1f}",
            f"{r['ref_ms']:.1f}",
            f"{r['split_ms'] / r['ref_ms']:.2f}x",  # type: ignore[operator]
        )
    console.print(f)
    console.print(f"machine load average {os.getloadavg()[0]:.1f}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps({"objects": rows, "frames": frames, "load_average": os.getloadavg()[0]}, indent=2)
    )


if __name__ == "__main__":
    main()
