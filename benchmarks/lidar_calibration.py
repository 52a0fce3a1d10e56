"""LiDAR-to-LiDAR calibration on the simulator's LiDAR model: Snow Lion's three planes against plain ICP.

Run: python benchmarks/lidar_calibration.py [--trials 10] [--json out.json]

Scene: the default rig (32-channel front unit, 16-channel side units) standing in a flat world with a
wall corner ahead on each side (two 3 m walls and the ground: Snow Lion's target). Each trial casts fresh
sweeps (the model's own 2 cm range noise, its own seed) and perturbs the side unit's true mount by
0.2 m and 2 degrees along and about random directions (seeded). Compared per trial, median over trials,
on one core:

- ``planes``: ``calibrate_by_planes`` (seeded RANSAC planes, Kabsch + offsets, plane-to-plane refinement);
- ``small_gicp_icp``: what a user would otherwise run: small_gicp point-to-plane ICP, coarse to fine
  (0.25 / 0.1 / 0.05 m voxels, 1.5 / 0.3 / 0.1 m pairing), its answer taken as is;
- ``small_gicp_gicp``: the same with generalized ICP (Segal's plane-to-plane).

``calibrate_by_icp`` is that ICP with checks; it refuses these clouds (residual / convergence), which is
counted as ``icp_refused``. For contrast, the synthetic scene of the unit tests (dense, uniformly sampled
surfaces: a wall corner, boxes, poles; 2 cm range noise; a unit turned 60 degrees and tilted) with the
same kind of random perturbation: ``synthetic_planes`` and ``synthetic_icp`` (``calibrate_by_icp``, which
is at home there); their time ratio is to ``synthetic_icp``.

Printed: position and rotation error against the true mount (median, p95, max), the share within issue
19's 2 cm / 0.1 degree, ms per calibration (median) with the ratio to the ICP, and a reference operation
(a cKDTree build and query of the two clouds) measured in the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.localization.lidar_scene import sweep, to_base  # noqa: E402
from tests.localization.test_lidar_calibration import REFERENCE, TRUE_MOUNT  # noqa: E402
from tests.localization.test_lidar_calibration_sim import GEOMETRY, RIG, corner_scene  # noqa: E402

from lastmile.core.errors import CalibrationError  # noqa: E402
from lastmile.core.stamp import Stamp  # noqa: E402
from lastmile.localization.lidar_calibration import (  # noqa: E402
    calibrate_by_icp,
    calibrate_by_planes,
    mount_difference,
)
from lastmile.sim.lidar import LidarSimulator  # noqa: E402
from lastmile.sim.lidar_rig import EgoTrack  # noqa: E402
from lastmile.sim.lidar_scene import DynamicObjects  # noqa: E402
from lastmile.sim.lidar_weather import LidarWeather  # noqa: E402

SIM_METHODS = ("planes", "small_gicp_icp", "small_gicp_gicp")
METHODS = (*SIM_METHODS, "synthetic_planes", "synthetic_icp")
BASELINE = {
    "planes": "small_gicp_icp",
    "small_gicp_icp": "small_gicp_icp",
    "small_gicp_gicp": "small_gicp_icp",
}
BASELINE |= {"synthetic_planes": "synthetic_icp", "synthetic_icp": "synthetic_icp"}


def plain_small_gicp(ref: np.ndarray, other: np.ndarray, init: np.ndarray, kind: str) -> np.ndarray:
    import small_gicp

    pose = init
    for voxel_m, corr_m in ((0.25, 1.5), (0.1, 0.3), (0.05, 0.1)):
        target, tree = small_gicp.preprocess_points(ref, downsampling_resolution=voxel_m, num_neighbors=15)
        source, _ = small_gicp.preprocess_points(other, downsampling_resolution=voxel_m, num_neighbors=15)
        result = small_gicp.align(
            target, source, tree, init_T_target_source=pose, registration_type=kind,
            max_correspondence_distance=corr_m, max_iterations=50,
        )  # fmt: skip
        pose = np.array(result.T_target_source)
    return pose


def _run(name: str, ref: np.ndarray, other: np.ndarray, nominal: np.ndarray, front: np.ndarray) -> np.ndarray:
    if name == "planes":
        return calibrate_by_planes(ref, other, nominal, front[:3, 3]).base_from_sensor
    return plain_small_gicp(ref, other, nominal, "PLANE_ICP" if name == "small_gicp_icp" else "GICP")


def perturb(mount: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    out = mount.copy()
    direction = rng.normal(size=3)
    axis = rng.normal(size=3)
    out[:3, 3] += 0.2 * direction / np.linalg.norm(direction)
    turn = Rotation.from_rotvec(math.radians(2.0) * axis / np.linalg.norm(axis)).as_matrix()
    out[:3, :3] = turn @ mount[:3, :3]
    return out


def _synthetic(
    trial: int,
    rng: np.random.Generator,
    errors: dict[str, list[tuple[float, float]]],
    times: dict[str, list[float]],
) -> None:
    """One calibration per method on the unit tests' synthetic scene."""
    scene_rng = np.random.default_rng(1000 + trial)
    ref = to_base(sweep(scene_rng, REFERENCE, density=20.0), REFERENCE)
    other = sweep(scene_rng, TRUE_MOUNT, density=20.0)
    nominal = perturb(TRUE_MOUNT, rng)
    for name in ("synthetic_planes", "synthetic_icp"):
        start = time.perf_counter()
        if name == "synthetic_planes":
            pose = calibrate_by_planes(ref, other, nominal, REFERENCE[:3, 3]).base_from_sensor
        else:
            pose = calibrate_by_icp(ref, other, nominal).base_from_sensor
        times[name].append((time.perf_counter() - start) * 1e3)
        errors[name].append(mount_difference(TRUE_MOUNT, pose))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rng = np.random.default_rng(19)
    front = RIG["front"].base_from_sensor
    errors: dict[str, list[tuple[float, float]]] = {m: [] for m in METHODS}
    times: dict[str, list[float]] = {m: [] for m in METHODS}
    refused = 0
    ref_ms: list[float] = []
    still = EgoTrack.constant(0, 0.0, 0.0, 0.0)
    for trial in range(args.trials):
        lidar = LidarSimulator(corner_scene(), tuple(RIG.values()), LidarWeather(), trial, GEOMETRY)
        fs = lidar.sweep("front", Stamp(0), still, DynamicObjects.empty(), 0)
        ref = fs.points[:, :3].astype(np.float64) @ front[:3, :3].T + front[:3, 3]
        for side in ("left", "right"):
            truth = RIG[side].base_from_sensor
            other = (
                lidar.sweep(side, Stamp(0), still, DynamicObjects.empty(), 0).points[:, :3].astype(np.float64)
            )
            nominal = perturb(truth, rng)
            start = time.perf_counter()
            cKDTree(ref).query(other)
            ref_ms.append((time.perf_counter() - start) * 1e3)
            for name in SIM_METHODS:
                start = time.perf_counter()
                pose = _run(name, ref, other, nominal, front)
                times[name].append((time.perf_counter() - start) * 1e3)
                errors[name].append(mount_difference(truth, pose))
            try:
                calibrate_by_icp(ref, other, nominal)
            except CalibrationError:
                refused += 1
        _synthetic(trial, rng, errors, times)
    load = os.getloadavg()[0]
    n = 2 * args.trials  # simulator calibrations (two side units per trial); the synthetic: one per trial
    table = Table(
        title=f"LiDAR calibration, default rig at a wall corner, {n} calibrations (load {load:.2f})"
    )
    for col in ("method", "pos cm median", "p95", "max", "rot deg median", "p95", "max", "within 2cm/0.1deg",
                "ms median", "x ICP time"):  # fmt: skip
        table.add_column(col, justify="right")
    report: dict[str, object] = {
        "load_1min": load,
        "calibrations": n,
        "reference_kdtree_build_query_ms": statistics.median(ref_ms),
        "calibrate_by_icp_refused": refused,
        "methods": {},
    }
    for name in METHODS:
        pos = np.array([e[0] for e in errors[name]]) * 100
        rot = np.degrees([e[1] for e in errors[name]])
        ok = float(np.mean((pos < 2.0) & (rot < 0.1)))
        med = statistics.median(times[name])
        base_ms = statistics.median(times[BASELINE[name]])
        row = {
            "pos_cm_median": float(np.median(pos)), "pos_cm_p95": float(np.percentile(pos, 95)),
            "pos_cm_max": float(pos.max()), "rot_deg_median": float(np.median(rot)),
            "rot_deg_p95": float(np.percentile(rot, 95)), "rot_deg_max": float(rot.max()),
            "share_within_target": ok, "ms_median": med, "time_vs_icp": med / base_ms,
        }  # fmt: skip
        report["methods"][name] = row  # type: ignore[index]
        table.add_row(
            name, *(f"{row[k]:.2f}" for k in ("pos_cm_median", "pos_cm_p95", "pos_cm_max")),
            *(f"{row[k]:.3f}" for k in ("rot_deg_median", "rot_deg_p95", "rot_deg_max")),
            f"{ok:.0%}", f"{med:.0f}", f"{med / base_ms:.2f}",
        )  # fmt: skip
    Console(width=170).print(table)
    print(f"calibrate_by_icp (ICP with its checks) refused {refused} of {n}")
    print(f"reference: cKDTree build + query of the two clouds: {statistics.median(ref_ms):.1f} ms")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
