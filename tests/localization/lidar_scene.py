"""A synthetic calibration scene: the ground, a wall corner, boxes and a pole, seen by two LiDARs.

Each sensor samples its own points on the surfaces (no point is shared, as two real LiDARs never hit
the same spot), keeps those within its range, adds range noise along its rays and expresses them in its
own frame.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

RANGE_NOISE_M = 0.02


def pose(xyz: tuple[float, float, float], rpy_deg: tuple[float, float, float]) -> np.ndarray:
    """A (4, 4) pose from a position and roll, pitch, yaw in degrees."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()
    out[:3, 3] = xyz
    return out


def perturbed(mount: np.ndarray, shift_m: float, turn_deg: float) -> np.ndarray:
    """``mount`` moved by ``shift_m`` and turned by ``turn_deg``, along axes no frame axis aligns with."""
    out = mount.copy()
    direction = np.array([1.0, -2.0, 0.7])
    axis = np.array([1.0, 2.0, 3.0])
    out[:3, 3] += shift_m * direction / np.linalg.norm(direction)
    turn = Rotation.from_rotvec(math.radians(turn_deg) * axis / np.linalg.norm(axis)).as_matrix()
    out[:3, :3] = turn @ mount[:3, :3]
    return out


def _rect(rng: np.random.Generator, n: int, origin, u, v) -> np.ndarray:
    a = rng.random((n, 1))
    b = rng.random((n, 1))
    return np.asarray(origin) + a * np.asarray(u) + b * np.asarray(v)


def _box(rng: np.random.Generator, n: int, cx: float, cy: float, size, yaw_deg: float) -> np.ndarray:
    sx, sy, sz = size
    faces = [
        ((-sx / 2, -sy / 2, 0), (sx, 0, 0), (0, 0, sz)),
        ((-sx / 2, sy / 2, 0), (sx, 0, 0), (0, 0, sz)),
        ((-sx / 2, -sy / 2, 0), (0, sy, 0), (0, 0, sz)),
        ((sx / 2, -sy / 2, 0), (0, sy, 0), (0, 0, sz)),
        ((-sx / 2, -sy / 2, sz), (sx, 0, 0), (0, sy, 0)),
    ]
    pts = np.vstack([_rect(rng, n // 5, *face) for face in faces])
    rot = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    return pts @ rot.T + np.array([cx, cy, 0.0])


def _pole(rng: np.random.Generator, n: int, cx: float, cy: float, radius: float, height: float) -> np.ndarray:
    ang = rng.random(n) * 2 * math.pi
    return np.column_stack([cx + radius * np.cos(ang), cy + radius * np.sin(ang), rng.random(n) * height])


def surfaces(rng: np.random.Generator, density: float, corner: bool = True) -> np.ndarray:
    """Points on the scene's surfaces (base frame), ``density`` per square metre."""
    parts = [_rect(rng, int(600 * density), (-10, -10, 0), (30, 0, 0), (0, 20, 0))]  # ground
    if corner:
        parts.append(_rect(rng, int(80 * density), (15, -10, 0), (0, 20, 0), (0, 0, 4)))  # wall x = 15
        parts.append(_rect(rng, int(100 * density), (-10, 9, 0), (25, 0, 0), (0, 0, 4)))  # wall y = 9
    parts.append(_box(rng, int(10 * density), 6.0, -4.0, (1.5, 1.0, 1.2), 20.0))
    parts.append(_box(rng, int(8 * density), 10.0, 5.0, (1.0, 1.0, 0.8), -35.0))
    parts.append(_pole(rng, int(3 * density), 8.0, 2.0, 0.15, 3.0))
    parts.append(_pole(rng, int(3 * density), 3.0, -6.0, 0.1, 2.5))
    return np.vstack(parts)


def sweep(
    rng: np.random.Generator, base_from_sensor: np.ndarray, density: float = 40.0, corner: bool = True
) -> np.ndarray:
    """The sensor's own sample of the scene, in its frame, with range noise along its rays."""
    pts = surfaces(rng, density, corner)
    local = (pts - base_from_sensor[:3, 3]) @ base_from_sensor[:3, :3]
    ranges = np.linalg.norm(local, axis=1)
    keep = (ranges > 0.5) & (ranges < 30.0)
    local, ranges = local[keep], ranges[keep]
    noisy = ranges + rng.normal(0.0, RANGE_NOISE_M, ranges.shape)
    return local * (noisy / ranges)[:, None]


def to_base(points: np.ndarray, base_from_sensor: np.ndarray) -> np.ndarray:
    return points @ base_from_sensor[:3, :3].T + base_from_sensor[:3, 3]
