"""Planes for Snow Lion's three-plane LiDAR calibration: seeded RANSAC extraction, matching, closed form.

Snow Lion ("Multilidar calibration") calibrates each pair of LiDARs on three linearly independent planar
surfaces in a wall-corner configuration: the corresponding planes are matched, the rotation comes from
the closed-form Kabsch algorithm on their normals and the translation from their offsets, then
plane-to-plane ICP refines it (``lidar_calibration.py``). This file holds the plane part.

A plane is ``n . x = d`` with a unit normal ``n`` that points towards the sensor that saw it (``d < 0``
in the sensor's own frame): two sensors looking at the same side of a wall then agree on its normal's
sign, which a plain SVD fit leaves arbitrary.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import CalibrationError, ConfigError


@dataclass(frozen=True, slots=True, kw_only=True)
class PlaneConfig:
    """Parameters of the RANSAC plane extraction and of the plane matching.

    Attributes:
        distance_m: a point within this of a plane is its inlier, m (about three times a LiDAR's
            1-sigma range noise of 2-3 cm, Velodyne VLP-32C / Ouster OS1 datasheets).
        iterations: RANSAC hypotheses per plane (three-point samples); 200 find a plane holding 30 % of
            the remaining points with probability 1 - (1 - 0.3^3)^200 = 99.6 %. Extraction is sequential:
            once the ground (most of a sweep) is removed, a wall is a large share of what remains.
        min_points: a plane needs at least this many inliers.
        max_planes: planes extracted per cloud, largest first.
        min_independence: three normals are independent when the smallest singular value of the 3x3
            matrix they form is at least this (0.3: no two of them within about 25 degrees of each
            other, nor all three within that of one plane).
        max_match_angle_rad: planes of the two clouds correspond when, under the nominal mount, their
            normals differ by at most this, rad (bounds how wrong the nominal rotation may be).
        max_match_offset_m: and their offsets along the normal by at most this, m (the same for the
            nominal translation).
        seed: seed of the RANSAC sampler; one seed gives the same planes every run.
    """

    distance_m: float = 0.06
    iterations: int = 200
    min_points: int = 200
    max_planes: int = 6
    min_independence: float = 0.3
    max_match_angle_rad: float = math.radians(10.0)
    max_match_offset_m: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("distance_m", "min_independence", "max_match_angle_rad", "max_match_offset_m"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"PlaneConfig.{name}: expected a positive number, got {value!r}")
        if self.iterations < 1 or self.min_points < 3 or self.max_planes < 3:
            raise ConfigError(
                "PlaneConfig: expected iterations >= 1, min_points >= 3 and max_planes >= 3, got "
                f"{self.iterations}, {self.min_points} and {self.max_planes}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class Plane:
    """A plane ``normal . x = offset_m`` fitted to ``inliers`` points.

    Attributes:
        normal: (3,) unit normal, towards the sensor that saw the plane.
        offset_m: signed offset along the normal, m.
        inliers: points within :attr:`PlaneConfig.distance_m` of it.
        rms_m: root-mean-square distance of those points to it, m.
        points: (inliers, 3) the inlier points themselves, in the frame the plane was fitted in (the
            plane-to-plane refinement moves them; :meth:`transformed` leaves them as they were).
    """

    normal: np.ndarray
    offset_m: float
    inliers: int
    rms_m: float
    points: np.ndarray

    def transformed(self, target_from_source: np.ndarray) -> Plane:
        """The same plane expressed in another frame, ``x_target = R x_source + t``."""
        rot = target_from_source[:3, :3]
        normal = rot @ self.normal
        return Plane(
            normal=normal,
            offset_m=float(self.offset_m + normal @ target_from_source[:3, 3]),
            inliers=self.inliers,
            rms_m=self.rms_m,
            points=self.points,
        )


def extract_planes(points: np.ndarray, viewpoint: np.ndarray, config: PlaneConfig) -> list[Plane]:
    """Sequential RANSAC: the largest plane, its inliers removed, the next, up to ``max_planes``.

    Args:
        points: (N, 3) float points, m.
        viewpoint: (3,) the sensor's origin in the points' frame; normals are turned towards it.
        config: thresholds and the seed.

    Returns:
        Planes, largest first (each refitted by least squares on its inliers).
    """
    rng = np.random.default_rng(config.seed)
    remaining = np.asarray(points, dtype=np.float64)
    planes: list[Plane] = []
    while len(planes) < config.max_planes and remaining.shape[0] >= config.min_points:
        found = _ransac_plane(remaining, rng, config)
        if found is None:
            break
        plane, mask = found
        planes.append(_oriented(plane, viewpoint))
        remaining = remaining[~mask]
    return planes


def independent_triple(planes: list[Plane], config: PlaneConfig, what: str) -> list[Plane]:
    """The largest three planes whose normals are mutually independent (a wall corner and the ground).

    Raises:
        CalibrationError: no three planes of the list are independent.
    """
    best: list[Plane] | None = None
    best_support = -1
    n = len(planes)
    for i in range(n):
        for j in range(i + 1, n):
            for k in range(j + 1, n):
                triple = [planes[i], planes[j], planes[k]]
                normals = np.array([p.normal for p in triple])
                if np.linalg.svd(normals, compute_uv=False)[-1] < config.min_independence:
                    continue
                support = sum(p.inliers for p in triple)
                if support > best_support:
                    best, best_support = triple, support
    if best is None:
        raise CalibrationError(
            f"{what}: expected three mutually non-parallel planes (a wall corner and the ground) of at "
            f"least {config.min_points} points each, got {n} plane(s) and no independent three"
        )
    return best


def match_planes(
    reference: list[Plane], other_in_reference: list[Plane], config: PlaneConfig
) -> list[tuple[Plane, Plane]]:
    """Pair each reference plane with the other cloud's plane nearest to it under the nominal mount.

    Both lists are in the reference frame. A pair needs normals within ``max_match_angle_rad`` and
    offsets within ``max_match_offset_m``; each plane is used at most once.
    """
    pairs: list[tuple[Plane, Plane]] = []
    used: set[int] = set()
    cos_limit = math.cos(config.max_match_angle_rad)
    for ref in reference:
        best, best_cost = -1, math.inf
        for idx, cand in enumerate(other_in_reference):
            if idx in used:
                continue
            cos = float(ref.normal @ cand.normal)
            gap = abs(ref.offset_m - cand.offset_m)
            if cos < cos_limit or gap > config.max_match_offset_m:
                continue
            cost = (1.0 - cos) / (1.0 - cos_limit) + gap / config.max_match_offset_m
            if cost < best_cost:
                best, best_cost = idx, cost
        if best >= 0:
            used.add(best)
            pairs.append((ref, other_in_reference[best]))
    return pairs


def closed_form_mount(pairs: list[tuple[Plane, Plane]]) -> np.ndarray:
    """Kabsch on the normals for the rotation, a linear solve of the offsets for the translation.

    Args:
        pairs: (reference plane in the reference frame, other plane in the other sensor's frame), at
            least three with independent normals.

    Returns:
        (4, 4) reference_from_other.

    With ``x_ref = R x_other + t``, a plane ``n_o . x_other = d_o`` becomes ``(R n_o) . x_ref = d_o +
    (R n_o) . t``; matching it to ``n_r . x_ref = d_r`` gives ``R n_o = n_r`` (Kabsch, weighted by inlier
    count) and ``n_r . t = d_r - d_o``, three equations (least squares over more) for ``t``.
    """
    ref_n = np.array([r.normal for r, _ in pairs])
    oth_n = np.array([o.normal for _, o in pairs])
    weights = np.array([min(r.inliers, o.inliers) for r, o in pairs], dtype=np.float64)
    cross = (oth_n * weights[:, None]).T @ ref_n
    u, _, vt = np.linalg.svd(cross)
    sign = 1.0 if np.linalg.det(vt.T @ u.T) > 0 else -1.0
    rot = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    rhs = np.array([r.offset_m - o.offset_m for r, o in pairs])
    trans = np.linalg.lstsq(ref_n, rhs, rcond=None)[0]
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = trans
    return out


def _ransac_plane(
    points: np.ndarray, rng: np.random.Generator, config: PlaneConfig
) -> tuple[Plane, np.ndarray] | None:
    """The plane with the most inliers among ``iterations`` three-point hypotheses, refitted."""
    n = points.shape[0]
    samples = rng.integers(0, n, size=(config.iterations, 3))
    a, b, c = points[samples[:, 0]], points[samples[:, 1]], points[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / norms[ok, None]
    offsets = np.einsum("ij,ij->i", normals, a[ok])
    best_mask: np.ndarray | None = None
    best_count = 0
    for normal, offset in zip(normals, offsets, strict=True):
        mask = np.abs(points @ normal - offset) <= config.distance_m
        count = int(mask.sum())
        if count > best_count:
            best_mask, best_count = mask, count
    if best_mask is None or best_count < config.min_points:
        return None
    # Refit on the inliers, then take the refit's inliers (a hypothesis through three noisy points is
    # tilted; the least-squares plane through its inliers is not).
    normal, offset = _fit(points[best_mask])
    mask = np.abs(points @ normal - offset) <= config.distance_m
    if int(mask.sum()) < config.min_points:
        return None
    normal, offset = _fit(points[mask])
    residual = points[mask] @ normal - offset
    plane = Plane(
        normal=normal,
        offset_m=offset,
        inliers=int(mask.sum()),
        rms_m=float(np.sqrt(np.mean(residual**2))),
        points=points[mask],
    )
    return plane, mask


def _fit(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane: the normal is the direction of least spread about the centroid."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[-1]
    return normal, float(normal @ centroid)


def _oriented(plane: Plane, viewpoint: np.ndarray) -> Plane:
    """The plane with its normal turned towards ``viewpoint``."""
    if float(plane.normal @ viewpoint) - plane.offset_m >= 0.0:
        return plane
    return Plane(
        normal=-plane.normal,
        offset_m=-plane.offset_m,
        inliers=plane.inliers,
        rms_m=plane.rms_m,
        points=plane.points,
    )


def refine_on_planes(pairs: list[tuple[Plane, Plane]], initial: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """Plane-to-plane refinement: the mount that puts the other cloud's plane points on the reference planes.

    Snow Lion refines the closed-form estimate by plane-to-plane ICP. The correspondences here are the
    matched planes themselves, each fitted to all its inliers: a point's residual is its distance to the
    whole reference plane, not to a plane through its nearest neighbours. A LiDAR's points on the
    ground lie on rings metres apart, where a neighbourhood is a line and its normal is arbitrary; a
    nearest-neighbour ICP drifts on them (a few centimetres and half a degree on the simulator's rig),
    a fitted plane does not. Each plane's residuals are weighted by one over the square root of its
    point count, so the ground's thousands of points do not outvote a wall's hundreds.

    Args:
        pairs: (reference plane in the reference frame, other plane with its points in its own frame).
        initial: (4, 4) reference_from_other to start from.

    Returns:
        (reference_from_other, RMS point-to-plane distance in m (unweighted), converged).
    """
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    normals = np.vstack([np.repeat(r.normal[None, :], len(o.points), axis=0) for r, o in pairs])
    offsets = np.concatenate([np.full(len(o.points), r.offset_m) for r, o in pairs])
    weights = np.concatenate([np.full(len(o.points), 1.0 / math.sqrt(len(o.points))) for _, o in pairs])
    points = np.vstack([o.points for _, o in pairs])

    def pose(x: np.ndarray) -> np.ndarray:
        delta = np.eye(4)
        delta[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
        delta[:3, 3] = x[3:]
        return delta @ initial

    def residual(x: np.ndarray) -> np.ndarray:
        m = pose(x)
        moved = points @ m[:3, :3].T + m[:3, 3]
        return weights * (np.einsum("ij,ij->i", moved, normals) - offsets)

    fit = least_squares(residual, np.zeros(6), method="lm", xtol=1e-12, ftol=1e-12)
    out = pose(fit.x)
    raw = fit.fun / weights
    return out, float(np.sqrt(np.mean(raw**2))), bool(fit.success)
