"""Bit-identity check of the LiDAR pipeline's outputs against a snapshot from an earlier version.

Speed-ups of the pipeline must not change a single output bit. Before changing the code, save a
snapshot; after, compare against it:

    python benchmarks/perception_identity.py save /tmp/pipeline_before.npz
    python benchmarks/perception_identity.py compare /tmp/pipeline_before.npz

Frames: 4 synthetic three-LiDAR rig frames (the speed benchmark's, map curb given), 2 frames of the
simulator's own rig (clear and snow, as the speed benchmark makes them) and, when the KITTI data is
present, the 3 KITTI object frames twice: with ring and time made up as the speed benchmark's
clustering rows do, and as ``lastmile perceive`` reads the ``.bin`` files (no curb). Compared element
by element: the cropped cloud, ground, noise, labels, curb obstacle and surface points, the cluster
table, hulls and labels.
Exit status 1 on any difference.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from tests.perception import kitti  # noqa: E402

from lastmile.perception.motion_compensation import PoseTrajectory, se3_matrix  # noqa: E402
from lastmile.perception.pipeline import LidarPipeline  # noqa: E402
from perception_speed import _kitti_sweep, _rig_frame, _sim_rig_frames, kitti_frames  # noqa: E402

RIG_SEEDS = (0, 1, 2, 3)


def outputs() -> dict[str, np.ndarray]:
    """Every compared array of every frame, keyed ``<frame>/<name>``."""
    pipe = LidarPipeline()
    out: dict[str, np.ndarray] = {}
    runs = []
    for seed in RIG_SEEDS:
        sweeps, ext, traj, curb = _rig_frame(seed)
        runs.append((f"rig{seed}", pipe.process(sweeps, ext, traj, None, curb)))
    k_ext = {"velodyne": se3_matrix(0.0, 0.0, kitti.VELODYNE_HEIGHT_M, 0.0, 0.0, 0.0)}
    k_traj = PoseTrajectory(
        stamps_us=np.array([-100_000, 0, 100_000, 200_000]),
        xyz_m=np.zeros((4, 3)),
        quat_xyzw=np.tile([0, 0, 0, 1.0], (4, 1)),
    )
    for name in kitti.frame_names():
        runs.append((f"kitti{name}", pipe.process([_kitti_sweep(kitti.load_frame(name))], k_ext, k_traj)))
    for name, (sweeps, ext, traj, curb) in kitti_frames():
        runs.append((f"perceive {name}", pipe.process(sweeps, ext, traj, None, curb)))
    for weather in ("clear", "snow"):
        sweeps, ext, traj, curb = _sim_rig_frames(weather, 1)[0]
        runs.append((f"sim {weather}", pipe.process(sweeps, ext, traj, None, curb)))
    for frame, r in runs:
        arrays = {
            "cloud": r.cloud.points,
            "source_index": r.source_index,
            "ground": r.ground,
            "noise": r.noise,
            "labels": r.labels,
            "curb_obstacle": r.curb_obstacle,
            "curb_surface": r.curb_surface,
            "table": r.clusters.table,
            "hull_xy": r.clusters.hull_xy,
            "hull_new": r.clusters.hull_new,
            "cluster_labels": r.clusters.labels,
        }
        if r.curb is not None:
            arrays["curb_obstacle_idx"] = np.asarray(r.curb.obstacle_idx)
            arrays["curb_surface_idx"] = np.asarray(r.curb.surface_idx)
        for k, v in arrays.items():
            out[f"{frame}/{k}"] = np.asarray(v)
    return out


def compare(saved: dict[str, np.ndarray], now: dict[str, np.ndarray]) -> list[str]:
    """Names of arrays that differ (dtype, shape or any element; NaNs equal to NaNs)."""
    bad = sorted(set(saved) ^ set(now))
    for k in sorted(set(saved) & set(now)):
        a, b = saved[k], now[k]
        same = a.dtype == b.dtype and a.shape == b.shape
        if same:
            same = bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
        if not same:
            bad.append(k)
    return bad


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("action", choices=("save", "compare"))
    parser.add_argument("path", type=Path)
    args = parser.parse_args()
    now = outputs()
    if args.action == "save":
        np.savez_compressed(args.path, **{k.replace("/", "__"): v for k, v in now.items()})
        print(f"saved {len(now)} arrays to {args.path}")
        return
    with np.load(args.path) as f:
        saved = {k.replace("__", "/"): f[k] for k in f.files}
    bad = compare(saved, now)
    frames = sorted({k.split("/")[0] for k in now})
    if bad:
        print(f"DIFFERENT in {len(bad)} of {len(now)} arrays: {', '.join(bad[:20])}")
        sys.exit(1)
    print(f"bit-identical: {len(now)} arrays over {len(frames)} frames ({', '.join(frames)})")


if __name__ == "__main__":
    main()
