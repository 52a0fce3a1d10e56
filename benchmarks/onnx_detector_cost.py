"""What the ONNX LiDAR detector plug-in costs besides the network itself, on the real KITTI frames.

Run: python benchmarks/onnx_detector_cost.py [--repeats 7] [--json out.json]
One core (BLAS and ONNX Runtime 1 thread), CPU time (``time.process_time``), medians of ``--repeats``.
Per KITTI object frame in ../shared/data/kitti_object (velodyne 1.73 m up, so the road is z = 0):

- the BEV raster of the default grid (PointPillars' KITTI grid, 432 x 496 cells of 0.16 m, channels
  max height, max intensity, density): ours (``bev_raster.bev_tensor``) against what a user would
  otherwise write, SciPy's ``binned_statistic_2d`` (max z, max intensity, count), checked equal;
- the plug-in's call around a model (``OnnxLidarDetector.detect``: raster, session run, output checks,
  circle NMS) with the tests' tiny weightless BEV peak model (so the figure is the plug-in's overhead,
  not a network's cost: a real detector adds its own inference time);
- beside them the reference operation of the perception benchmarks on the same frame: SciPy's
  ``cKDTree`` build plus one 0.5 m radius query, and each figure as a ratio to it.
The machine's load average is printed and stored.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.spatial import cKDTree
from scipy.stats import binned_statistic_2d

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.perception.kitti import VELODYNE_HEIGHT_M, frame_names, load_frame  # noqa: E402
from tests.perception.tiny_onnx import bev_peak_detector  # noqa: E402

from lastmile.core.object_class import ObjectClass  # noqa: E402
from lastmile.perception.bev_raster import BevGrid, bev_tensor  # noqa: E402
from lastmile.perception.lidar_detector import LidarDetectorConfig, OnnxLidarDetector  # noqa: E402


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append((time.process_time() - t0) * 1e3)
    return statistics.median(times)


def _scipy_raster(xyz: np.ndarray, intensity: np.ndarray, grid: BevGrid) -> np.ndarray:
    """The same three channels with SciPy (max height, max intensity / 255, Complex-YOLO density)."""
    keep = (xyz[:, 2] >= grid.z_min_m) & (xyz[:, 2] < grid.z_max_m)
    x, y, z, i = xyz[keep, 0], xyz[keep, 1], xyz[keep, 2] - grid.z_min_m, intensity[keep] / 255.0
    bins = [grid.rows, grid.cols]
    rng = [[grid.x_min_m, grid.x_max_m], [grid.y_min_m, grid.y_max_m]]
    top = binned_statistic_2d(x, y, z, "max", bins=bins, range=rng).statistic
    bright = binned_statistic_2d(x, y, i, "max", bins=bins, range=rng).statistic
    count = binned_statistic_2d(x, y, None, "count", bins=bins, range=rng).statistic
    density = np.minimum(1.0, np.log1p(count) / np.log(64.0))
    out = np.stack([np.nan_to_num(top), np.nan_to_num(bright), density]).astype(np.float32)
    return out[None]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument(
        "--json", type=Path, default=ROOT / "benchmarks" / "results" / "onnx_detector_cost.json"
    )
    args = parser.parse_args()
    names = frame_names()
    if not names:
        sys.exit("KITTI object frames not found at <repo>/../shared/data/kitti_object")
    grid = BevGrid()
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        model = bev_peak_detector(
            Path(tmp) / "peaks.onnx",
            grid,
            threshold=1.5 - grid.z_min_m,  # height-map peaks 1.5 m above the road (channel from z_min_m)
            class_id=int(ObjectClass.CAR),
            box_lwh_m=(4.0, 1.8, 1.5),
        )
        detector = OnnxLidarDetector(LidarDetectorConfig(model=str(model), grid=grid))
        rows = []
        for name in names:
            velo = load_frame(name).velo
            xyz = velo[:, :3].astype(np.float64) + np.array([0.0, 0.0, VELODYNE_HEIGHT_M])
            inten = velo[:, 3].astype(np.float64) * 255.0  # KITTI's 0..1 reflectance on the 0..255 scale
            ours = bev_tensor(xyz, inten, grid)
            theirs = _scipy_raster(xyz, inten, grid)
            # binned_statistic_2d puts x == x_max in the last bin; the raster leaves it out (half-open).
            equal = bool(np.allclose(ours, theirs, atol=1e-6))
            ref = _median_ms(lambda xyz=xyz: cKDTree(xyz).query_ball_point(xyz[0], 0.5), args.repeats)
            raster = _median_ms(lambda xyz=xyz, inten=inten: bev_tensor(xyz, inten, grid), args.repeats)
            scipy = _median_ms(lambda xyz=xyz, inten=inten: _scipy_raster(xyz, inten, grid), args.repeats)
            call = _median_ms(lambda xyz=xyz, inten=inten: detector.detect(xyz, inten), args.repeats)
            rows.append(
                {
                    "frame": name,
                    "points": len(xyz),
                    "reference_kdtree_ms": ref,
                    "raster_ms": raster,
                    "scipy_raster_ms": scipy,
                    "raster_vs_scipy": scipy / raster,
                    "rasters_equal": equal,
                    "plugin_call_ms": call,
                    "plugin_call_vs_reference": call / ref,
                    "detections": len(detector.detect(xyz, inten)),
                }
            )
    table = Table(title=f"ONNX LiDAR detector plug-in, CPU ms (median of {args.repeats}), load {load[0]:.1f}")
    columns = ("frame", "points", "cKDTree ref", "raster", "SciPy raster", "SciPy / ours", "equal")
    for col in (*columns, "plug-in call", "call / ref", "detections"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            r["frame"], str(r["points"]), f"{r['reference_kdtree_ms']:.1f}", f"{r['raster_ms']:.1f}",
            f"{r['scipy_raster_ms']:.1f}", f"{r['raster_vs_scipy']:.2f}x", str(r["rasters_equal"]),
            f"{r['plugin_call_ms']:.1f}", f"{r['plugin_call_vs_reference']:.2f}x", str(r["detections"]),
        )  # fmt: skip
    Console(width=150).print(table)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {"load_average": load, "grid": list(grid.shape), "repeats": args.repeats, "frames": rows},
            indent=1,
        )
    )
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
