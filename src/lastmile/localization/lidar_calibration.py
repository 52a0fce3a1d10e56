"""LiDAR-to-LiDAR extrinsic calibration from recorded clouds: ICP, and Snow Lion's three-plane method.

- :func:`calibrate_by_icp` (WATonoBus, aUToronto 3.5): register the other LiDAR's cloud, in its own
  frame, to the reference LiDAR's cloud in the base frame, starting from the nominal mount; small_gicp
  point-to-plane ICP, coarse to fine.
- :func:`calibrate_by_planes` (Snow Lion, "Multilidar calibration"): three independent planes per cloud
  (seeded RANSAC, ``lidar_planes.py``), matched under the nominal mount, a closed-form estimate (Kabsch on
  the normals, a linear solve of the offsets), then a plane-to-plane refinement: the other cloud's plane
  points onto the matched reference planes, each plane fitted to all its inliers
  (``lidar_planes.refine_on_planes``). A nearest-neighbour ICP (point-to-plane or GICP) as the
  refinement was tried and dropped: on a ring LiDAR's ground, where neighbourhoods are lines, it moved a
  0.2 cm closed-form estimate to 3.7 cm and 0.6 degrees on the simulator's rig.

Both return the corrected 6-DoF mount (base_from_sensor) with its fitness (share of the other cloud's
points paired with the reference) and inlier RMSE, and raise :class:`CalibrationError` in one line when
the clouds overlap too little, the registration does not converge, or too few planes are found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
from scipy.spatial.transform import Rotation

from lastmile.core.errors import CalibrationError, ConfigError, MessageError
from lastmile.localization.lidar_planes import (
    PlaneConfig,
    closed_form_mount,
    extract_planes,
    independent_triple,
    match_planes,
    refine_on_planes,
)


class CalibrationMethod(Enum):
    """How a mount was estimated."""

    ICP = "icp"
    THREE_PLANES = "three_planes"


@dataclass(frozen=True, slots=True, kw_only=True)
class IcpCalibrationConfig:
    """Parameters of the registration.

    Attributes:
        voxels_m: voxel size of each coarse-to-fine stage, m.
        max_correspondences_m: largest pairing distance of each stage, m. The first bounds how wrong the
            nominal mount may be (0.2 m and 2 degrees move a point 20 m away by 0.9 m).
        neighbours: points per normal / covariance estimate.
        max_iterations: Gauss-Newton iterations per stage.
        rotation_epsilon_rad: a stage has converged when its last update turned less than this, rad.
        translation_epsilon_m: and moved less than this, m.
        overlap_m: a point of the other cloud overlaps the reference cloud when a reference point lies
            within this of it, m (more than the ring spacing of a 16-channel LiDAR 10 m away, 0.35 m).
        min_fitness: fewer of the other cloud's points overlapping the reference than this share means
            the two sensors do not see enough of the same surfaces (10 %: a side unit of a
            WATonoBus-style rig shares about a quarter of its view with the front unit).
        min_constraint_share: every translation direction and rotation axis must be held by pairs whose
            information along it is at least this share of the pairs (as if that share of the points
            lay on surfaces facing it; scan matching's 1 %, ``ScanMatchConfig.min_constraint_share``).
        max_rmse_m: a final inlier RMSE above this means the clouds were not brought together, m.
        min_points: a cloud needs at least this many points.
    """

    voxels_m: tuple[float, ...] = (0.25, 0.1, 0.05)
    max_correspondences_m: tuple[float, ...] = (1.5, 0.3, 0.1)
    neighbours: int = 15
    max_iterations: int = 50
    rotation_epsilon_rad: float = 1e-5
    translation_epsilon_m: float = 1e-5
    overlap_m: float = 0.5
    min_fitness: float = 0.1
    min_constraint_share: float = 0.01
    max_rmse_m: float = 0.05
    min_points: int = 500

    def __post_init__(self) -> None:
        stages = (self.voxels_m, self.max_correspondences_m)
        if not self.voxels_m or len(self.voxels_m) != len(self.max_correspondences_m):
            raise ConfigError(
                "IcpCalibrationConfig: expected as many voxels_m as max_correspondences_m (at least one), "
                f"got {len(self.voxels_m)} and {len(self.max_correspondences_m)}"
            )
        values = [*stages[0], *stages[1], self.rotation_epsilon_rad, self.translation_epsilon_m]
        values += [self.max_rmse_m, self.overlap_m, self.min_constraint_share]
        if not all(v > 0 and math.isfinite(v) for v in values):
            raise ConfigError(f"IcpCalibrationConfig: expected positive finite sizes, got {values}")
        if self.neighbours < 5 or self.max_iterations < 1 or self.min_points < 10:
            raise ConfigError(
                "IcpCalibrationConfig: expected neighbours >= 5, max_iterations >= 1, min_points >= 10, "
                f"got {self.neighbours}, {self.max_iterations}, {self.min_points}"
            )
        if not 0.0 < self.min_fitness <= 1.0:
            raise ConfigError(f"IcpCalibrationConfig.min_fitness: expected (0, 1], got {self.min_fitness}")


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarCalibration:
    """A calibrated mount.

    Attributes:
        base_from_sensor: (4, 4) float64 the corrected mount.
        nominal_base_from_sensor: (4, 4) float64 the mount it started from.
        correction_m: distance between the two mounts' origins, m.
        correction_rad: angle of the rotation between them, rad.
        fitness: share of the other cloud's (downsampled) points within ``overlap_m`` of the reference.
        rmse_m: root-mean-square distance of those points to the reference's local planes, m.
        iterations: registration iterations over all stages (0 for the plane refinement).
        method: how it was estimated.
        initial_base_from_sensor: (4, 4) the closed-form three-plane estimate the ICP started from
            (the nominal mount for :attr:`CalibrationMethod.ICP`).
    """

    base_from_sensor: np.ndarray
    nominal_base_from_sensor: np.ndarray
    correction_m: float
    correction_rad: float
    fitness: float
    rmse_m: float
    iterations: int
    method: CalibrationMethod
    initial_base_from_sensor: np.ndarray


def calibrate_by_icp(
    reference_base: np.ndarray,
    other_sensor: np.ndarray,
    nominal_base_from_sensor: np.ndarray,
    config: IcpCalibrationConfig | None = None,
) -> LidarCalibration:
    """The other LiDAR's mount by point-to-plane ICP against the reference LiDAR's cloud.

    Args:
        reference_base: (N, 3) the reference LiDAR's points in the base frame (its mount known), m.
        other_sensor: (M, 3) the other LiDAR's points in its own frame, m.
        nominal_base_from_sensor: (4, 4) the other LiDAR's nominal mount, the initial guess.
        config: registration parameters.

    Raises:
        MessageError: bad shapes or non-finite values.
        CalibrationError: too little overlap, no convergence, or residuals too large.
    """
    c = config or IcpCalibrationConfig()
    ref = _points("reference cloud", reference_base, c.min_points)
    oth = _points("other cloud", other_sensor, c.min_points)
    nominal = _pose("nominal mount", nominal_base_from_sensor)
    return _register(ref, oth, nominal, nominal, c, CalibrationMethod.ICP, "PLANE_ICP")


def calibrate_by_planes(
    reference_base: np.ndarray,
    other_sensor: np.ndarray,
    nominal_base_from_sensor: np.ndarray,
    reference_origin_base: np.ndarray,
    config: IcpCalibrationConfig | None = None,
    planes: PlaneConfig | None = None,
) -> LidarCalibration:
    """Snow Lion's method: three matched planes, closed form (Kabsch + offsets), plane-to-plane refinement.

    Args:
        reference_base: (N, 3) the reference LiDAR's points in the base frame, m.
        other_sensor: (M, 3) the other LiDAR's points in its own frame, m.
        nominal_base_from_sensor: (4, 4) the other LiDAR's nominal mount; it matches the planes.
        reference_origin_base: (3,) the reference LiDAR's origin in the base frame (orients normals).
        config: the overlap (``overlap_m``, ``min_fitness``, ``voxels_m[-1]``) and residual
            (``max_rmse_m``) checks.
        planes: extraction and matching parameters.

    Raises:
        MessageError: bad shapes or non-finite values.
        CalibrationError: fewer than three independent planes in either cloud or matched between them;
            the refinement's overlap, convergence or residual checks.
    """
    c = config or IcpCalibrationConfig()
    p = planes or PlaneConfig()
    ref = _points("reference cloud", reference_base, c.min_points)
    oth = _points("other cloud", other_sensor, c.min_points)
    nominal = _pose("nominal mount", nominal_base_from_sensor)
    origin = np.asarray(reference_origin_base, dtype=np.float64)
    if origin.shape != (3,) or not np.isfinite(origin).all():
        raise MessageError(f"reference origin: expected a finite (3,) point, got shape {origin.shape}")
    ref_planes = extract_planes(ref, origin, p)
    independent_triple(ref_planes, p, "reference cloud")
    oth_planes = extract_planes(oth, np.zeros(3), p)
    independent_triple(oth_planes, p, "other cloud")
    moved = [pl.transformed(nominal) for pl in oth_planes]
    pairs = match_planes(ref_planes, moved, p)
    by_id = {id(m): o for m, o in zip(moved, oth_planes, strict=True)}
    native = [(r, by_id[id(m)]) for r, m in pairs]
    try:
        triple = independent_triple([r for r, _ in native], p, "matched planes")
    except CalibrationError:
        raise CalibrationError(
            f"matched planes: expected three independent planes of the reference matched under the "
            f"nominal mount (normals within {math.degrees(p.max_match_angle_rad):.0f} deg, offsets "
            f"within {p.max_match_offset_m} m), got {len(native)} pair(s) without an independent three"
        ) from None
    chosen = [pair for pair in native if any(pair[0] is t for t in triple)]
    initial = closed_form_mount(chosen)
    pose, rmse_m, converged = refine_on_planes(native, initial)
    # Every matched plane pair holds the mount along its normal, and three of them are independent:
    # the constraint is that of the planes, so only overlap, convergence and residual are checked.
    fitness = _overlap(ref, oth, pose, c)
    quality = _Quality(fitness, rmse_m, math.inf, "translation", np.zeros(3))
    _check(quality, converged, c, CalibrationMethod.THREE_PLANES)
    return _calibration(nominal, pose, quality, 0, CalibrationMethod.THREE_PLANES, initial)


def _overlap(ref: np.ndarray, oth: np.ndarray, pose: np.ndarray, c: IcpCalibrationConfig) -> float:
    """Share of the other cloud's points (downsampled to the finest voxel) near a reference point."""
    import small_gicp
    from scipy.spatial import cKDTree

    voxel_m = c.voxels_m[-1]
    tgt = np.asarray(small_gicp.voxelgrid_sampling(ref, voxel_m).points(), dtype=np.float64)[:, :3]
    src = np.asarray(small_gicp.voxelgrid_sampling(oth, voxel_m).points(), dtype=np.float64)[:, :3]
    moved = src @ pose[:3, :3].T + pose[:3, 3]
    dist, _ = cKDTree(tgt).query(moved, distance_upper_bound=c.overlap_m)
    return float(np.isfinite(dist).mean())


def mount_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Distance between two poses' origins (m) and the angle of the rotation between them (rad)."""
    delta = np.linalg.inv(a) @ b
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), float(
        np.linalg.norm(Rotation.from_matrix(delta[:3, :3]).as_rotvec())
    )


def _register(
    ref: np.ndarray,
    oth: np.ndarray,
    initial: np.ndarray,
    nominal: np.ndarray,
    c: IcpCalibrationConfig,
    method: CalibrationMethod,
    registration: str,
) -> LidarCalibration:
    """Coarse-to-fine small_gicp registration of ``oth`` (sensor frame) to ``ref`` (base frame)."""
    import small_gicp

    pose = initial.copy()
    iterations = 0
    result = None
    for voxel_m, corr_m in zip(c.voxels_m, c.max_correspondences_m, strict=True):
        target, tree = small_gicp.preprocess_points(
            ref, downsampling_resolution=voxel_m, num_neighbors=c.neighbours
        )
        source, _ = small_gicp.preprocess_points(
            oth, downsampling_resolution=voxel_m, num_neighbors=c.neighbours
        )
        result = small_gicp.align(
            target,
            source,
            tree,
            init_T_target_source=pose,
            registration_type=registration,
            max_correspondence_distance=corr_m,
            max_iterations=c.max_iterations,
            rotation_epsilon=c.rotation_epsilon_rad,
            translation_epsilon=c.translation_epsilon_m,
        )
        pose = np.array(result.T_target_source, dtype=np.float64)
        iterations += int(result.iterations)
    assert result is not None  # at least one stage (checked by the config)
    quality = _fit_quality(target, source, pose, c.overlap_m)
    _check(quality, bool(result.converged), c, method)
    return _calibration(nominal, pose, quality, iterations, method, initial)


def _calibration(
    nominal: np.ndarray,
    pose: np.ndarray,
    quality: _Quality,
    iterations: int,
    method: CalibrationMethod,
    initial: np.ndarray,
) -> LidarCalibration:
    corr_m, corr_rad = mount_difference(nominal, pose)
    return LidarCalibration(
        base_from_sensor=pose,
        nominal_base_from_sensor=nominal,
        correction_m=corr_m,
        correction_rad=corr_rad,
        fitness=quality.fitness,
        rmse_m=quality.rmse_m,
        iterations=iterations,
        method=method,
        initial_base_from_sensor=initial,
    )


def _check(quality: _Quality, converged: bool, c: IcpCalibrationConfig, method: CalibrationMethod) -> None:
    """Raise the first failed check, the most basic first: overlap, constraint, convergence, residual."""
    fitness, rmse_m = quality.fitness, quality.rmse_m
    label = f"{method.value} calibration"
    if fitness < c.min_fitness:
        raise CalibrationError(
            f"{label}: expected at least {c.min_fitness:.0%} of the other LiDAR's "
            f"points within {c.overlap_m} m of the reference cloud, got {fitness:.1%} "
            "(too little overlap, or the nominal mount is too far off)"
        )
    if quality.weakest_share < c.min_constraint_share:
        axis = ", ".join(f"{v:+.2f}" for v in quality.weakest_axis)
        way = "along" if quality.weakest_kind == "translation" else "about"
        raise CalibrationError(
            f"{label}: expected the surfaces both LiDARs see to hold every direction of "
            f"the mount (at least {c.min_constraint_share:.0%} of the pairs), got {quality.weakest_kind} "
            f"{way} ({axis}) held by {quality.weakest_share:.2%} (degenerate overlap: Snow Lion's "
            "wall corner and the ground in view of both hold all six)"
        )
    if not converged:
        raise CalibrationError(
            f"{label}: expected the registration to converge within "
            f"{c.max_iterations} iterations, got no convergence (fitness {fitness:.2f}, RMSE {rmse_m:.3f} m)"
        )
    if rmse_m > c.max_rmse_m:
        raise CalibrationError(
            f"{label}: expected an inlier RMSE within {c.max_rmse_m} m, got {rmse_m:.3f} m"
        )


@dataclass(frozen=True, slots=True)
class _Quality:
    fitness: float
    rmse_m: float
    weakest_share: float
    weakest_kind: str
    weakest_axis: np.ndarray


def _fit_quality(target: object, source: object, pose: np.ndarray, max_distance_m: float) -> _Quality:
    """How well, and how firmly, the registered source lies on the target.

    Fitness is the share of the source's points within ``max_distance_m`` of the target; the RMSE is
    their distance to the target's local plane, m (the same measure for both costs: GICP's own error
    is a Mahalanobis distance, not metres). The constraint is that of point-to-plane pairs (Zhang et
    al., ICRA 2016): a translation along ``v`` moves a pair's residual by ``n . v`` and a small rotation
    about ``w`` through the sensor by ``(p x n) . w`` (``p`` from the sensor, taken per metre of range);
    the smallest eigenvalue of each 3x3 mean information, as a share of the pairs, says how firmly the
    least held direction is held.
    """
    from scipy.spatial import cKDTree

    tgt = np.asarray(target.points(), dtype=np.float64)[:, :3]  # type: ignore[attr-defined]
    normals = np.asarray(target.normals(), dtype=np.float64)[:, :3]  # type: ignore[attr-defined]
    src = np.asarray(source.points(), dtype=np.float64)[:, :3]  # type: ignore[attr-defined]
    moved = src @ pose[:3, :3].T + pose[:3, 3]
    dist, idx = cKDTree(tgt).query(moved, distance_upper_bound=max_distance_m)
    paired = np.isfinite(dist)
    if paired.sum() < 6:
        return _Quality(float(paired.mean()), math.inf, 0.0, "translation", np.array([1.0, 0.0, 0.0]))
    n = normals[idx[paired]]
    residual = np.einsum("ij,ij->i", moved[paired] - tgt[idx[paired]], n)
    arm = moved[paired] - pose[:3, 3]
    lever = np.cross(arm, n) / np.maximum(np.linalg.norm(arm, axis=1), 1e-6)[:, None]
    weakest = (math.inf, "translation", np.zeros(3))
    for kind, rows in (("translation", n), ("rotation", lever)):
        vals, vecs = np.linalg.eigh(rows.T @ rows / rows.shape[0])
        if vals[0] < weakest[0]:
            weakest = (float(vals[0]), kind, vecs[:, 0])
    return _Quality(
        fitness=float(paired.mean()),
        rmse_m=float(np.sqrt(np.mean(residual**2))),
        weakest_share=weakest[0],
        weakest_kind=weakest[1],
        weakest_axis=weakest[2],
    )


def _points(what: str, points: np.ndarray, minimum: int) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise MessageError(f"{what}: expected an (N, 3) array of points, got shape {arr.shape}")
    finite = np.isfinite(arr).all(axis=1)
    if not finite.all():
        raise MessageError(
            f"{what}: expected finite coordinates, got {int((~finite).sum())} NaN/inf point(s)"
        )
    if arr.shape[0] < minimum:
        raise CalibrationError(f"{what}: expected at least {minimum} points, got {arr.shape[0]}")
    return arr


def _pose(what: str, pose: np.ndarray) -> np.ndarray:
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape != (4, 4) or not np.isfinite(arr).all():
        raise MessageError(f"{what}: expected a finite (4, 4) pose, got shape {arr.shape}")
    rot = arr[:3, :3]
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or abs(np.linalg.det(rot) - 1.0) > 1e-6:
        raise MessageError(
            f"{what}: expected a rotation matrix in the upper-left 3x3, got det {np.linalg.det(rot):.6f}"
        )
    return arr
