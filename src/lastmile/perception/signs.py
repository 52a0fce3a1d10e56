"""GEM's five-stage retro-reflective sign detection (section VI) and the stop-sign deceleration.

Stages on the base-frame cloud: (1) field of view: ahead of the vehicle and within +/- 10 m to the
side; (2) minimum intensity (85 on a VLP-16's 0..255 scale, retro-reflective sheeting returns
~200+); (3) radius outlier removal: fewer than 3 neighbours within 0.5 m; (4) statistical outlier
removal: mean distance to the k nearest neighbours beyond mean + std_ratio * std of all points;
(5) RANSAC plane; the sign must face the vehicle: |n_x| >= 0.9 for the unit normal (a, b, c).
The distance to the sign feeds ``a = -v^2 / (2 d)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from lastmile.core.errors import ConfigError, MessageError


@dataclass(frozen=True, slots=True, kw_only=True)
class SignDetectorConfig:
    """Attributes (GEM's values as defaults):
    side_clearance_m: stage 1 half-width of the field of view.
    max_range_m: stage 1 depth limit ahead.
    min_intensity: stage 2 threshold (0..255).
    ror_radius_m, ror_min_neighbours: stage 3.
    sor_k, sor_std_ratio: stage 4 (PCL's meanK and stddevMulThresh).
    ransac_threshold_m, ransac_iterations: stage 5 inlier distance and trials.
    min_facing: smallest |n_x| of the plane's unit normal (GEM: a >= 0.9).
    min_points: fewer inliers than this is no sign (GEM reliable from ~40 points at 10 m).
    """

    side_clearance_m: float = 10.0
    max_range_m: float = 40.0
    min_intensity: float = 85.0
    ror_radius_m: float = 0.5
    ror_min_neighbours: int = 3
    sor_k: int = 8
    sor_std_ratio: float = 1.0
    ransac_threshold_m: float = 0.05
    ransac_iterations: int = 100
    min_facing: float = 0.9
    min_points: int = 5

    def __post_init__(self) -> None:
        for name in ("side_clearance_m", "max_range_m", "ror_radius_m", "ransac_threshold_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"SignDetectorConfig.{name}: expected a positive number, got {v}")
        if self.sor_k < 1 or self.ror_min_neighbours < 1 or self.ransac_iterations < 1 or self.min_points < 3:
            raise ConfigError(f"SignDetectorConfig: expected positive counts and min_points >= 3, got {self}")
        if not 0 < self.min_facing <= 1:
            raise ConfigError(f"SignDetectorConfig.min_facing: expected in (0, 1], got {self.min_facing}")


@dataclass(frozen=True, slots=True, kw_only=True)
class SignDetection:
    """The sign facing the vehicle: the facing plane with the most RANSAC inliers (GEM keeps one per frame,
    which is not necessarily the nearest; a caller that wants the lane's own sign narrows the cloud first).

    Attributes:
        distance_m: horizontal distance from the base origin to the inliers' centroid.
        centroid_m: (3,) inlier centroid, base frame.
        normal: (3,) unit plane normal, pointing toward the vehicle (n_x <= 0).
        inlier_idx: (K,) int64 indices into the input cloud.
        stage_counts: points left after each of the five stages.
    """

    distance_m: float
    centroid_m: np.ndarray
    normal: np.ndarray
    inlier_idx: np.ndarray
    stage_counts: tuple[int, int, int, int, int]


def stop_deceleration_mps2(speed_mps: float, distance_m: float) -> float:
    """GEM's constant deceleration to stop at a sign: a = -v^2 / (2 d) (negative: braking).

    Raises:
        MessageError: a negative speed or a non-positive distance.
    """
    if not (math.isfinite(speed_mps) and speed_mps >= 0):
        raise MessageError(f"stop_deceleration_mps2: expected speed >= 0, got {speed_mps}")
    if not (math.isfinite(distance_m) and distance_m > 0):
        raise MessageError(f"stop_deceleration_mps2: expected distance > 0, got {distance_m}")
    return -(speed_mps**2) / (2.0 * distance_m)


def detect_sign(
    xyz_m: npt.ArrayLike,
    intensity: npt.ArrayLike,
    rng: np.random.Generator,
    config: SignDetectorConfig | None = None,
) -> SignDetection | None:
    """Run the five stages; None when no facing sign survives.

    Args:
        xyz_m: (N, 3) base-frame points (x forward).
        intensity: (N,) intensities, 0..255.
        rng: the generator RANSAC draws from (seeded by the caller: one seed, one result).
    """
    cfg = config or SignDetectorConfig()
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    inten = np.asarray(intensity, dtype=np.float64).reshape(-1)
    if len(inten) != len(p):
        raise MessageError(f"detect_sign: expected one intensity per point, got {len(inten)} for {len(p)}")
    idx = np.flatnonzero(
        (p[:, 0] > 0) & (p[:, 0] <= cfg.max_range_m) & (np.abs(p[:, 1]) <= cfg.side_clearance_m)
    )
    n1 = len(idx)
    idx = idx[inten[idx] >= cfg.min_intensity]
    n2 = len(idx)
    if n2 < cfg.min_points:
        return None
    tree = cKDTree(p[idx])
    nb = np.asarray(tree.query_ball_point(p[idx], cfg.ror_radius_m, return_length=True)) - 1
    idx = idx[nb >= cfg.ror_min_neighbours]
    n3 = len(idx)
    if n3 < cfg.min_points:
        return None
    k = min(cfg.sor_k, n3 - 1)
    dist, _ = cKDTree(p[idx]).query(p[idx], k=k + 1)
    mean_d = dist[:, 1:].mean(axis=1)
    idx = idx[mean_d <= mean_d.mean() + cfg.sor_std_ratio * mean_d.std()]
    n4 = len(idx)
    if n4 < cfg.min_points:
        return None
    q = p[idx]
    best_in: np.ndarray | None = None
    best_n = np.zeros(3)
    for _ in range(cfg.ransac_iterations):
        a, b, c = q[rng.choice(len(q), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-9:
            continue
        n = n / norm
        # Only planes facing the vehicle are sign candidates (GEM checks a >= 0.9 on the model).
        if abs(n[0]) < cfg.min_facing:
            continue
        inl = np.abs((q - a) @ n) <= cfg.ransac_threshold_m
        if best_in is None or inl.sum() > best_in.sum():
            best_in, best_n = inl, n
    if best_in is None or best_in.sum() < cfg.min_points:
        return None
    # Refit the plane to the inliers (least squares through the centroid).
    pts = q[best_in]
    centroid = pts.mean(axis=0)
    normal = np.linalg.svd(pts - centroid, full_matrices=False)[2][-1]
    if abs(normal[0]) < cfg.min_facing:
        normal = best_n
    if normal[0] > 0:
        normal = -normal
    return SignDetection(
        distance_m=float(np.hypot(centroid[0], centroid[1])),
        centroid_m=centroid,
        normal=normal,
        inlier_idx=idx[best_in].astype(np.int64),
        stage_counts=(n1, n2, n3, n4, int(best_in.sum())),
    )
