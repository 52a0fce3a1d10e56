"""Compiles every perception kernel into the user's cache ahead of the first run (``lastmile warmup``).

The kernels are compiled for the argument types they are called with, so they are warmed by running
the pipeline itself, not by calling the kernels with stand-in arrays: a small synthetic scene (a road
with raised sidewalks, a street 1.7 m lower beyond it, a car, a pedestrian, snowflakes near the
sensors) seen by a 32-beam and a 16-beam spinning LiDAR, through every path a run can take: with an
INS trajectory, the road mask and the curb stage (the stack's closed loop), without them (``lastmile
perceive`` on files), and with Himmelsbach as the ground segmenter. The lower street makes the
adaptive grid's level-change fallback run Himmelsbach's kernels; the flakes make DROR run its
scan-pattern test. Afterwards every kernel function Python calls must hold a compiled signature,
else :func:`warm_up` says which did not.

``python -m lastmile.perception.warmup`` is the same as ``lastmile warmup``.
"""

from __future__ import annotations

import math
import sys
import time
from types import ModuleType

import numpy as np

from lastmile.core.kernel_warmup import WarmupReport, print_report, warmup_report
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.perception import (
    cluster_geometry_kernel,
    clustering_kernel,
    curbs_kernel,
    deskew_kernel,
    dror_kernel,
    ground_kernel,
    himmelsbach_kernel,
)
from lastmile.perception.motion_compensation import PoseTrajectory
from lastmile.perception.pipeline import LidarPipeline, LidarPipelineConfig

KERNEL_MODULES: tuple[ModuleType, ...] = (
    cluster_geometry_kernel,
    clustering_kernel,
    curbs_kernel,
    deskew_kernel,
    dror_kernel,
    ground_kernel,
    himmelsbach_kernel,
)
SWEEP_US = 100_000
SPEED_MPS = 4.0
_ROAD_HALF_WIDTH_M = 3.5
_SIDEWALK_M = 0.15
_LOWER_STREET = (22.0, 6.0, -1.7)  # x beyond, |y| beyond, height: a street below a retaining wall
# (centre x, centre y, length, width, height) in the base frame
_BOXES = ((10.0, -1.5, 4.5, 1.8, 1.5), (15.0, 2.0, 0.5, 0.5, 1.75), (8.0, 4.2, 0.6, 0.3, 0.4))


def _sweep(
    sensor_id: str, z_m: float, elevations_deg: np.ndarray, columns: int, rng: np.random.Generator
) -> LidarSweep:
    """A spinning LiDAR at (0, 0, z_m) of the base frame: each ray's first hit of the boxes or the
    terrain, plus snowflakes within 8 m. Points in the sensor frame, ring = beam index from the
    lowest, time from the azimuth."""
    az = np.linspace(-math.pi, math.pi, columns, endpoint=False)
    el = np.radians(np.sort(elevations_deg))
    A, E = np.meshgrid(az, el)
    ring = np.broadcast_to(np.arange(len(el))[:, None], A.shape)
    c, s, t = np.cos(A), np.sin(A), np.tan(E)
    # Rays at or above the horizon hit the ground nowhere: 1e9 m stands for "no hit".
    r = np.where(t < 0, z_m / np.maximum(-t, 1e-9), 1e9)
    x, y = r * c, r * s
    ground = np.where(np.abs(y) > _ROAD_HALF_WIDTH_M, _SIDEWALK_M, 0.0)
    lower = (x > _LOWER_STREET[0]) & (np.abs(y) > _LOWER_STREET[1])
    r = np.where(
        lower,
        (z_m - _LOWER_STREET[2]) / np.maximum(-t, 1e-9),
        np.where(ground > 0, (z_m - _SIDEWALK_M) / np.maximum(-t, 1e-9), r),
    )
    z = np.where(lower, _LOWER_STREET[2], ground)
    for bx, by, bl, bw, bh in _BOXES:
        # 2-D slab test of the ray against the box, then the beam's height at that distance.
        with np.errstate(divide="ignore", invalid="ignore"):
            t1x, t2x = (bx - bl / 2 - 0) / c, (bx + bl / 2) / c
            t1y, t2y = (by - bw / 2) / s, (by + bw / 2) / s
        near = np.maximum(np.minimum(t1x, t2x), np.minimum(t1y, t2y))
        far = np.minimum(np.maximum(t1x, t2x), np.maximum(t1y, t2y))
        h = z_m + near * t
        hit = (near <= far) & (near > 0) & (near < r) & (h >= 0.0) & (h <= bh)
        r = np.where(hit, near, r)
        z = np.where(hit, h, z)
    ok = r < 80.0
    pts = np.column_stack(
        [
            (r * c)[ok],
            (r * s)[ok],
            z[ok] - z_m,
            rng.uniform(5.0, 60.0, ok.sum()),
            ring[ok],
            ((A[ok] + math.pi) / (2 * math.pi) * SWEEP_US),
        ]
    )
    flakes = rng.uniform(
        [-8.0, -8.0, -z_m + 0.3, 80.0, 0.0, 0.0], [8.0, 8.0, 2.0, 200.0, len(el) - 1, SWEEP_US], (150, 6)
    )
    flakes[:, 4] = np.round(flakes[:, 4])
    return LidarSweep(stamp=Stamp(0), sensor_id=sensor_id, points=np.vstack([pts, flakes]).astype(np.float32))


def _frame() -> tuple[list[LidarSweep], dict[str, np.ndarray], PoseTrajectory]:
    rng = np.random.default_rng(0)
    mounts = {"front": 1.9, "side": 0.9}
    sweeps = [
        _sweep("front", mounts["front"], np.linspace(-25.0, 15.0, 32), 900, rng),
        _sweep("side", mounts["side"], np.linspace(-60.0, 10.0, 16), 900, rng),
    ]
    extrinsics = {}
    for sid, z in mounts.items():
        m = np.eye(4)
        m[2, 3] = z
        extrinsics[sid] = m
    stamps = np.arange(-50_000, SWEEP_US + 50_001, 10_000, dtype=np.int64)
    traj = PoseTrajectory(
        stamps_us=stamps,
        xyz_m=np.column_stack([SPEED_MPS * stamps / 1e6, np.zeros((len(stamps), 2))]),
        quat_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (len(stamps), 1)),
    )
    return sweeps, extrinsics, traj


def _kernel_functions() -> dict[str, object]:
    """Every Numba-compiled function of the kernel modules, by qualified name."""
    out: dict[str, object] = {}
    for module in KERNEL_MODULES:
        for name, value in vars(module).items():
            own = getattr(getattr(value, "py_func", None), "__module__", None) == module.__name__
            if own and hasattr(value, "signatures"):
                out[f"{module.__name__.rsplit('.', 1)[-1]}.{name}"] = value
    return out


def entry_kernels() -> dict[str, object]:
    """The kernel functions Python calls (the private ``_helpers`` are compiled into their callers
    and hold no signature of their own)."""
    return {name: fn for name, fn in _kernel_functions().items() if not name.split(".")[-1].startswith("_")}


def warm_up() -> WarmupReport:
    """Run the pipeline through every path once so that each kernel is compiled (or loaded)."""
    t0 = time.perf_counter()
    sweeps, extrinsics, traj = _frame()

    def road(xy: np.ndarray) -> np.ndarray:
        return np.abs(xy[:, 1]) <= _ROAD_HALF_WIDTH_M

    curb = np.array([[-20.0, -_ROAD_HALF_WIDTH_M], [60.0, -_ROAD_HALF_WIDTH_M]])
    grid = LidarPipeline()
    grid.process(sweeps, extrinsics, traj, road, curb, [curb, curb * [1.0, -1.0]])
    grid.process(sweeps, extrinsics)
    LidarPipeline(LidarPipelineConfig(ground="himmelsbach")).process(sweeps, extrinsics, traj, road, curb)
    kernels = entry_kernels()
    return warmup_report(kernels, t0)


def main() -> int:
    return print_report("perception", warm_up())


if __name__ == "__main__":
    sys.exit(main())
