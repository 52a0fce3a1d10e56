"""Synthetic LiDAR scenes for perception tests and benchmarks: a straight road with curbs, objects, snow.

Rays are cast analytically: the terrain height depends on y only (a lateral profile of road, curb,
sidewalk and snow bank, piecewise linear) plus a constant longitudinal grade, so each ray meets each
profile piece at most once; boxes are intersected with the slab method. Every point keeps its ring
and time offset, so the clouds exercise de-skewing and merging like a real spinning LiDAR.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.perception.motion_compensation import se3_matrix

# Velodyne VLP-32C beam elevations: dense around the horizon, where small far objects are.
VLP32_ELEVATIONS_DEG = (
    -25.0,
    -15.639,
    -11.31,
    -8.843,
    -7.254,
    -6.148,
    -5.333,
    -4.667,
    -4.0,
    -3.667,
    -3.333,
    -3.0,
    -2.667,
    -2.333,
    -2.0,
    -1.667,
    -1.333,
    -1.0,
    -0.667,
    -0.333,
    0.0,
    0.333,
    0.667,
    1.0,
    1.333,
    1.667,
    2.333,
    3.333,
    4.667,
    7.0,
    10.333,
    15.0,
)
BLIND_SPOT_ELEVATIONS_DEG = tuple(np.linspace(-60.0, 30.0, 16))  # wide vertical FOV units


@dataclass(frozen=True)
class Box:
    """Axis-aligned box in the world frame; ``retro`` marks retro-reflective sheeting."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    retro: bool = False
    label: int = 0


@dataclass(frozen=True)
class Scene:
    """Terrain profile over y (knots ascending) with a grade along x, and boxes."""

    profile_y: tuple[float, ...] = (-5.0, -3.5, -3.49, 3.49, 3.5, 5.0)
    profile_z: tuple[float, ...] = (0.15, 0.15, 0.0, 0.0, 0.15, 0.15)
    grade: float = 0.0
    boxes: tuple[Box, ...] = field(default_factory=tuple)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.grade * x + np.interp(y, self.profile_y, self.profile_z)


@dataclass(frozen=True)
class Lidar:
    sensor_id: str
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    elevations_deg: tuple[float, ...]
    azimuth_res_deg: float = 0.2
    max_range_m: float = 100.0
    az_min_rad: float = -math.pi
    az_max_rad: float = math.pi

    @property
    def base_from_sensor(self) -> np.ndarray:
        return se3_matrix(self.x_m, self.y_m, self.z_m, 0.0, 0.0, self.yaw_rad)


def default_rig() -> tuple[Lidar, ...]:
    """WATonoBus-like: a 32-channel unit on the nose, 16-channel blind-spot units on both sides."""
    return (
        Lidar("front", 3.9, 0.0, 1.9, 0.0, VLP32_ELEVATIONS_DEG, 0.2),
        Lidar("left", 1.5, 1.1, 0.9, math.pi / 2, BLIND_SPOT_ELEVATIONS_DEG, 0.2, 40.0),
        Lidar("right", 1.5, -1.1, 0.9, -math.pi / 2, BLIND_SPOT_ELEVATIONS_DEG, 0.2, 40.0),
    )


def cast(
    scene: Scene, origin: np.ndarray, dirs: np.ndarray, max_range: float
) -> tuple[np.ndarray, np.ndarray]:
    """Range (N,) to the first hit of each unit ray (inf if none) and the hit box index (-1 terrain)."""
    ox, oy, oz = origin
    dx, dy, dz = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    Y = np.asarray(scene.profile_y)
    Z = np.asarray(scene.profile_z)
    best = np.full(len(dirs), np.inf)
    # Pieces: (-inf, Y0), [Y0, Y1], ..., (Y_{K-1}, inf); on each the terrain is z = g x + z_j + m_j (y - Y_j).
    slopes = np.diff(Z) / np.diff(Y)
    pieces = [(-np.inf, Y[0], Z[0], 0.0, Y[0])]
    pieces += [(Y[j], Y[j + 1], Z[j], slopes[j], Y[j]) for j in range(len(Y) - 1)]
    pieces.append((Y[-1], np.inf, Z[-1], 0.0, Y[-1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        for y_lo, y_hi, z_j, m_j, y_j in pieces:
            # oz + t dz = g (ox + t dx) + z_j + m_j (oy + t dy - y_j)
            num = scene.grade * ox + z_j + m_j * (oy - y_j) - oz
            den = dz - scene.grade * dx - m_j * dy
            t = num / den
            y_hit = oy + t * dy
            ok = (t > 0) & (y_hit >= y_lo) & (y_hit <= y_hi) & np.isfinite(t)
            best = np.where(ok & (t < best), t, best)
        hit_box = np.full(len(dirs), -1)
        for k, b in enumerate(scene.boxes):
            lo = (np.asarray(b.lo) - origin)[None, :] / dirs
            hi = (np.asarray(b.hi) - origin)[None, :] / dirs
            tmin = np.nanmax(np.minimum(lo, hi), axis=1)
            tmax = np.nanmin(np.maximum(lo, hi), axis=1)
            ok = (tmax >= tmin) & (tmax > 0) & (tmin > 0) & (tmin < best)
            best = np.where(ok, tmin, best)
            hit_box = np.where(ok, k, hit_box)
    best[best > max_range] = np.inf
    return best, hit_box


def sweep(
    scene: Scene,
    lidar: Lidar,
    stamp_us: int,
    rng: np.random.Generator,
    *,
    ego_speed_mps: float = 0.0,
    period_us: int = 100_000,
    snowflakes: int = 0,
    range_noise_m: float = 0.01,
) -> tuple[LidarSweep, np.ndarray]:
    """One sweep in the sensor frame, the vehicle driving along +x at ``ego_speed_mps``.

    Returns the sweep and the (N,) box index each point hit (-1 terrain, -2 snowflake).
    """
    elev = np.radians(np.asarray(lidar.elevations_deg))
    n_az = round(360.0 / lidar.azimuth_res_deg)
    az = -math.pi + (np.arange(n_az) + 0.5) * (2 * math.pi / n_az)
    keep_az = (az >= lidar.az_min_rad) & (az <= lidar.az_max_rad)
    t_off = (np.arange(n_az) * (period_us / n_az)).astype(np.int64)
    az, t_off = az[keep_az], t_off[keep_az]
    A, E = np.meshgrid(az, elev, indexing="ij")
    T = np.repeat(t_off, len(elev))
    ring = np.tile(np.arange(len(elev)), len(az))
    A, E = A.ravel(), E.ravel()
    d_sensor = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=1)
    B = lidar.base_from_sensor
    d_world = d_sensor @ B[:3, :3].T
    out_r = np.full(len(A), np.inf)
    out_box = np.full(len(A), -1)
    # The vehicle moves during the sweep: cast each column group from where the sensor is then.
    groups = np.array_split(np.arange(len(A)), 100)  # 1 ms of motion per group
    for g in groups:
        t_s = (stamp_us + T[g].mean()) / 1e6
        origin = B[:3, 3] + np.array([ego_speed_mps * t_s, 0.0, 0.0])
        r, bx = cast(scene, origin, d_world[g], lidar.max_range_m)
        out_r[g], out_box[g] = r, bx
    hit = np.isfinite(out_r)
    r = out_r[hit] + rng.normal(0.0, range_noise_m, int(hit.sum()))
    # Points are reported in the sensor frame at their own capture time (the sensor moved with the bus).
    xyz = d_sensor[hit] * r[:, None]
    box = out_box[hit]
    retro = np.array([b.retro for b in scene.boxes] + [False])[box]
    intensity = np.where(retro, rng.uniform(200, 250, len(r)), rng.uniform(10, 60, len(r)))
    pts = np.column_stack([xyz, intensity, ring[hit], T[hit]])
    if snowflakes:
        fa = rng.uniform(-math.pi, math.pi, snowflakes)
        fe = rng.uniform(elev.min(), elev.max(), snowflakes)
        # A flake lies in the air: before the beam would reach the road (z = 0 under the sensor).
        to_ground = np.where(np.sin(fe) < 0, lidar.z_m / np.maximum(-np.sin(fe), 1e-6), np.inf)
        fr = rng.uniform(0.8, 1.0, snowflakes) * np.minimum(12.0, to_ground)
        flakes = np.column_stack(
            [
                fr * np.cos(fe) * np.cos(fa),
                fr * np.cos(fe) * np.sin(fa),
                fr * np.sin(fe),
                rng.uniform(0, 30, snowflakes),
                rng.integers(0, len(elev), snowflakes),
                rng.integers(0, period_us, snowflakes),
            ]
        )
        pts = np.vstack([pts, flakes])
        box = np.concatenate([box, np.full(snowflakes, -2)])
    return LidarSweep(stamp=Stamp(stamp_us), sensor_id=lidar.sensor_id, points=pts.astype(np.float32)), box


def campus_scene(rng: np.random.Generator, n_cars: int = 6, n_peds: int = 8, n_geese: int = 4) -> Scene:
    """A road with curbs, buildings on both sides, parked cars, pedestrians, geese, poles and signs."""
    boxes = [Box((-60, 9, 0), (80, 20, 8), label=9), Box((-60, -20, 0), (80, -9, 8), label=9)]
    for k in range(n_cars):  # one per 11 m slot, so no two cars overlap
        x = -20.0 + 11.0 * k + rng.uniform(0.0, 4.0)
        y = rng.choice([-2.0, 2.0])
        boxes.append(Box((x - 2.2, y - 0.9, 0.15), (x + 2.2, y + 0.9, 1.6), label=1))
    for _ in range(n_peds):
        x, y = rng.uniform(-15, 35), rng.uniform(-6, 6)
        boxes.append(Box((x - 0.25, y - 0.25, 0.0), (x + 0.25, y + 0.25, 1.75), label=2))
    for _ in range(n_geese):
        x, y = rng.uniform(5, 30), rng.uniform(-3, 3)
        boxes.append(Box((x - 0.3, y - 0.15, 0.0), (x + 0.3, y + 0.15, 0.4), label=4))
    for x in (10.0, 30.0, 50.0):
        boxes.append(Box((x - 0.08, -4.5, 0.15), (x + 0.08, -4.34, 4.0), label=8))
    boxes.append(Box((25.0, -4.6, 1.8), (25.03, -3.9, 2.5), retro=True, label=7))
    return Scene(boxes=tuple(boxes))


def base_cloud(
    scene: Scene, lidar: Lidar, rng: np.random.Generator, snowflakes: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A parked bus's sweep in the base frame: (N, 3) xyz, (N,) intensity, (N,) box index (-1, -2)."""
    sw, box = sweep(scene, lidar, 0, rng, snowflakes=snowflakes)
    p = sw.points.astype(np.float64)
    B = lidar.base_from_sensor
    xyz = p[:, :3] @ B[:3, :3].T + B[:3, 3]
    return xyz, p[:, 3], box
