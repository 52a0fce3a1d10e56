"""Simulated LiDAR rig speed: ms per 10 Hz rig frame (front 32-ch + two 16-ch units) on the campus map.

Run: python benchmarks/lidar_sim_speed.py [--frames 15] [--json out.json]
One core (BLAS pinned to one thread). Times are process CPU time (the machine is shared: the wall
clock of a frame, also reported, includes waiting for the core). Places along the ring with a car
ahead, an oncoming car, two pedestrians at the kerb and a goose in the lane; the shuttle moves at
5 m/s during each sweep.
Compared in the same run with the straightforward NumPy ray caster a user would write (every ray
against every primitive in reach, 3D slab / quadratic / wall tests broadcast over rays x primitives)
on a subset of the front unit's columns, extrapolated to the whole rig; the two must agree ray for ray.
Target (issue #3): the whole rig well under 30 ms per frame.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.campus_layout import RING
from lastmile.hdmap.loader import load_campus_map
from lastmile.sim.agents import Agent
from lastmile.sim.camera import CameraDetectorModel, CameraScene, default_cameras
from lastmile.sim.lidar import LidarSimulator
from lastmile.sim.lidar_raycast import cast
from lastmile.sim.lidar_rig import EgoTrack, default_lidar_rig
from lastmile.sim.lidar_scene import DynamicObjects, static_scene
from lastmile.sim.lidar_weather import lidar_weather
from lastmile.sim.weather import Weather

TARGET_MS = 30.0
PLACES = {
    "crosswalk C1": RING.s_of_x_bottom(150.0),
    "all-way stop": RING.s_of_x_bottom(355.0),
    "stop S1 / Eng 5": RING.s_of_x_bottom(530.0),
    "corner NE": RING.s_of_y_right(250.0),
    "crosswalk C3 / Arts": RING.s_of_x_top(320.0),
}


def lane_pose(s_m: float, d_m: float = -1.75) -> tuple[float, float, float]:
    x, y, h = RING.pose(s_m)
    return x - d_m * math.sin(h), y + d_m * math.cos(h), h


def agents_at(s_m: float) -> list[Agent]:
    def at(
        ds: float,
        d: float,
        cls: ObjectClass,
        length: float,
        width: float,
        speed: float,
        yaw_off: float,
        i: int,
    ) -> Agent:
        x, y, h = lane_pose(s_m + ds, d)
        return Agent(id=i, cls=cls, x_m=x, y_m=y, yaw_rad=h + yaw_off, speed_mps=speed, length_m=length,
                     width_m=width, rcs_dbsm=0.0)  # fmt: skip

    return [
        at(18.0, -1.75, ObjectClass.CAR, 4.5, 1.8, 4.0, 0.0, 1),
        at(30.0, 1.75, ObjectClass.CAR, 4.5, 1.8, 6.0, math.pi, 2),
        at(12.0, -4.5, ObjectClass.PEDESTRIAN, 0.5, 0.5, 0.0, math.pi / 2, 3),
        at(14.0, -4.8, ObjectClass.PEDESTRIAN, 0.5, 0.5, 0.0, math.pi / 2, 4),
        at(30.0, -1.0, ObjectClass.ANIMAL, 0.5, 0.3, 0.3, math.pi / 2, 5),
    ]


def brute_force_ranges(
    sim: LidarSimulator, spec_id: str, ego: EgoTrack, objects: DynamicObjects, every: int
) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Primitive casting only (no ground, weather, noise), ours on the whole sweep and the naive caster
    on every ``every``-th column: (our seconds per ray, naive seconds per ray, naive ranges, ours)."""
    spec = sim.specs[spec_id]
    order = np.argsort(spec.elevations_deg)
    tan = np.tan(np.radians(np.asarray(spec.elevations_deg)[order]))
    t_ours = time.process_time()
    cols, _ = sim.columns(spec, 0, ego, 100_000)
    table, pairs = sim.primitives(spec, cols, objects)
    ours_full = cast(cols, tan, (table["z_min"], table["z_max"]), pairs, spec.max_range_m).range_h_m
    ours_s = (time.process_time() - t_ours) / ours_full.size
    ours = ours_full[::every]
    # The primitive arrays as the naive caster sees them (all in reach; no pairing, no binning).
    reach = spec.max_range_m + 1.0
    centre = cols.origin[0]
    seg = sim.scene.segments
    mid = 0.5 * (seg.p0 + seg.p1)
    keep = np.hypot(*(mid - centre).T) - 0.5 * np.hypot(*(seg.p1 - seg.p0).T) <= reach
    if sim.weather.snow_on_road:
        keep &= seg.label != 2
    p0, p1, sz0, sz1 = seg.p0[keep], seg.p1[keep], seg.z_min_m[keep], seg.z_max_m[keep]
    cyl = sim.scene.cylinders
    kc = np.hypot(*(cyl.centre - centre).T) <= reach
    cc = np.concatenate([cyl.centre[kc], objects.cylinders.centre])
    cv = np.concatenate([cyl.velocity[kc], objects.cylinders.velocity])
    cr = np.concatenate([cyl.radius_m[kc], objects.cylinders.radius_m])
    cz0 = np.concatenate([cyl.z_min_m[kc], objects.cylinders.z_min_m])
    cz1 = np.concatenate([cyl.z_max_m[kc], objects.cylinders.z_max_m])
    bx = objects.boxes
    idx = np.arange(0, len(cols), every)
    t0 = time.process_time()
    o = cols.origin[idx][:, None, None, :]  # (C', 1, 1, 2)
    d = cols.direction[idx][:, None, None, :]
    tt = cols.t_s[idx][:, None, None]
    tz = tan[None, :, None]  # (1, K, 1): the ray is (o + r d, oz + r tan) in horizontal distance r
    oz = cols.z_m
    best = np.full((len(idx), len(tan)), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        # walls
        e = (p1 - p0)[None, None]
        w = p0[None, None] - o
        den = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
        r = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / den
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den
        z = oz + r * tz
        ok = (u >= 0) & (u <= 1) & (r > 0) & (z >= sz0) & (z <= sz1)
        best = np.minimum(best, np.where(ok, r, np.inf).min(axis=2))
        # cylinders (moving), with the z slab
        c = cc[None, None] + cv[None, None] * tt[..., None]
        rel = o - c
        b = (rel * d).sum(-1)
        disc = b * b - ((rel * rel).sum(-1) - cr**2)
        sq = np.sqrt(np.maximum(disc, 0))
        lo_z, hi_z = (cz0 - oz) / tz, (cz1 - oz) / tz
        r_in = np.maximum(-b - sq, np.minimum(lo_z, hi_z))
        r_out = np.minimum(-b + sq, np.maximum(lo_z, hi_z))
        ok = (disc >= 0) & (r_out >= r_in) & (r_out > 0)
        best = np.minimum(best, np.where(ok, np.maximum(r_in, 1e-6), np.inf).min(axis=2))
        # boxes (moving), 3D slab test
        cb = bx.centre[None, None] + bx.velocity[None, None] * tt[..., None]
        cy, sy = np.cos(bx.yaw_rad), np.sin(bx.yaw_rad)
        rx, ry = o[..., 0] - cb[..., 0], o[..., 1] - cb[..., 1]
        lx, ly = cy * rx + sy * ry, -sy * rx + cy * ry
        dx, dy = cy * d[..., 0] + sy * d[..., 1], -sy * d[..., 0] + cy * d[..., 1]
        ax1, ax2 = (-bx.half_length_m - lx) / dx, (bx.half_length_m - lx) / dx
        ay1, ay2 = (-bx.half_width_m - ly) / dy, (bx.half_width_m - ly) / dy
        az1, az2 = (bx.z_min_m - oz) / tz, (bx.z_max_m - oz) / tz
        r_in = np.maximum(np.maximum(np.minimum(ax1, ax2), np.minimum(ay1, ay2)), np.minimum(az1, az2))
        r_out = np.minimum(np.minimum(np.maximum(ax1, ax2), np.maximum(ay1, ay2)), np.maximum(az1, az2))
        ok = (r_out >= r_in) & (r_out > 0)
        best = np.minimum(best, np.where(ok, np.maximum(r_in, 1e-6), np.inf).min(axis=2))
    best[best > spec.max_range_m] = np.inf
    return (
        ours_s,
        (time.process_time() - t0) / best.size,
        best,
        np.where(ours > spec.max_range_m, np.inf, ours),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=15)
    parser.add_argument("--baseline-every", type=int, default=10, help="naive caster on every n-th column")
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/lidar_sim_speed.json"))
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    geometry = VehicleGeometry()
    rig = default_lidar_rig(geometry)
    t0 = time.perf_counter()
    scene = static_scene(load_campus_map())
    build_s = time.perf_counter() - t0
    rows = []
    for weather in ("clear", "snow"):
        sim = LidarSimulator(scene, rig, lidar_weather(weather), 0, geometry)
        for place, s in PLACES.items():
            times: list[float] = []
            walls: list[float] = []
            points: list[int] = []
            baseline: list[float] = []
            cast_only: list[float] = []
            agree: list[float] = []
            objects = DynamicObjects.from_agents(agents_at(s))
            for k in range(args.frames):
                x, y, h = lane_pose(s + 0.5 * k)
                ego = EgoTrack.constant(k * 100_000, x, y, h, speed_mps=5.0)
                stamp = Stamp(k * 100_000)
                t, tw = time.process_time(), time.perf_counter()
                sweeps = [
                    sim.sweep(spec.sensor_id, stamp, ego, objects, k * 100_000 + 100_000) for spec in rig
                ]
                times.append(time.process_time() - t)
                walls.append(time.perf_counter() - tw)
                points.append(sum(len(sw.points) for sw in sweeps))
                if k < 3:
                    ego0 = EgoTrack.constant(0, x, y, h, speed_mps=5.0)
                    ours_s, naive_s, naive, ours = brute_force_ranges(
                        sim, "front", ego0, objects, args.baseline_every
                    )
                    rays_rig = sum(sp.n_rays for sp in rig)
                    baseline.append(naive_s * rays_rig)
                    cast_only.append(ours_s * rays_rig)
                    agree.append(
                        float(
                            np.mean(np.isclose(naive, ours, atol=1e-6) | (np.isinf(naive) & np.isinf(ours)))
                        )
                    )
            rows.append(
                {
                    "weather": weather,
                    "place": place,
                    "ms_per_rig_frame": 1e3 * statistics.median(times),
                    "wall_ms_per_rig_frame": 1e3 * statistics.median(walls),
                    "points_per_frame": statistics.median(points),
                    "cast_ms_per_rig_frame": 1e3 * statistics.median(cast_only),
                    "naive_ms_per_rig_frame": 1e3 * statistics.median(baseline),
                    "naive_agreement": min(agree),
                }
            )
    table = Table(
        title=f"simulated LiDAR rig ({sum(s.n_rays for s in rig)} rays/frame), one core, "
        f"median of {args.frames} frames"
    )
    for col in (
        "weather",
        "place",
        "cpu ms/frame",
        "wall ms",
        "points",
        "cast ms",
        "naive cast ms",
        "speed-up",
        "rays agree",
        "vs 30 ms",
    ):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            r["weather"],
            r["place"],
            f"{r['ms_per_rig_frame']:.1f}",
            f"{r['wall_ms_per_rig_frame']:.1f}",
            f"{r['points_per_frame']:.0f}",
            f"{r['cast_ms_per_rig_frame']:.1f}",
            f"{r['naive_ms_per_rig_frame']:.0f}",
            f"{r['naive_ms_per_rig_frame'] / r['cast_ms_per_rig_frame']:.0f}x",
            f"{r['naive_agreement']:.4f}",
            f"{r['ms_per_rig_frame'] / TARGET_MS:.2f}",
        )
    # Camera detector (front + rear) on the same places, and points on a goose 30 m ahead.
    cams = [CameraDetectorModel(c, Weather.SNOW, 0.5, 0) for c in default_cameras(geometry)]
    cam_times = []
    for s in PLACES.values():
        x, y, h = lane_pose(s)
        cs = CameraScene.from_agents(SE2(x, y, h), agents_at(s))
        for k in range(args.frames):
            t = time.process_time()
            for cam in cams:
                cam.detect(cs, Stamp(k))
            cam_times.append(time.process_time() - t)
    cam_ms = 1e3 * statistics.median(cam_times)
    goose_points = {}
    for weather in ("clear", "snow", "fog"):
        sim = LidarSimulator(scene, rig, lidar_weather(weather), 0, geometry)
        s = PLACES["all-way stop"] - 40.0
        x, y, h = lane_pose(s)
        goose = Agent(id=99, cls=ObjectClass.ANIMAL, x_m=0.0, y_m=0.0, yaw_rad=h + math.pi / 2, speed_mps=0.0,
                      length_m=0.5, width_m=0.3, rcs_dbsm=-15.0)  # fmt: skip
        gx, gy, _ = lane_pose(s + 30.0 + rig[0].x_m)
        goose.x_m, goose.y_m = gx, gy
        counts = []
        for _ in range(args.frames):
            _, truth = sim.sweep_with_truth(
                "front", Stamp(0), EgoTrack.constant(0, x, y, h), DynamicObjects.from_agents([goose]), 0
            )
            counts.append(int((truth.object_id == 99).sum()))
        goose_points[weather] = statistics.median(counts)
    overall = statistics.median(r["ms_per_rig_frame"] for r in rows)
    ratio = statistics.median(r["naive_ms_per_rig_frame"] / r["cast_ms_per_rig_frame"] for r in rows)
    Console().print(table)
    Console().print(
        f"median {overall:.1f} ms (CPU) per rig frame (target < {TARGET_MS:g}); primitive casting: "
        f"naive NumPy all-rays x all-primitives {ratio:.0f}x slower; "
        f"static scene build {build_s:.2f} s"
    )
    Console().print(
        f"camera detector (front + rear, 5 road users, snow at dusk): {cam_ms:.2f} ms per frame pair; "
        f"points on a 0.5 x 0.3 x 0.4 m goose 30 m ahead (front unit): {goose_points}"
    )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "median_ms_per_rig_frame": overall,
                "target_ms": TARGET_MS,
                "median_speedup_vs_naive": ratio,
                "scene_build_s": build_s,
                "rays_per_frame": sum(s.n_rays for s in rig),
                "rows": rows,
                "camera_ms_per_frame_pair": cam_ms,
                "goose_points_at_30m": goose_points,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
