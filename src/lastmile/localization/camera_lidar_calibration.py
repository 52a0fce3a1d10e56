"""LiDAR-to-camera extrinsic calibration on a planar checkerboard (Zhang & Pless, IROS 2004).

Each view pairs an image and a LiDAR cloud of the same board. The camera gives the board's plane
(``checkerboard_detection.py``: corners, PnP); the LiDAR's board points are found near where the current
estimate of the mount puts the board (the nominal mount first), as the RANSAC plane there that faces the
way the board does. The mount ``camera_from_lidar`` (x_cam = R x_lidar + t) must put every LiDAR board
point on its view's camera plane ``n . x = d``:

1. closed form from the planes alone (the linear initialisation): the LiDAR plane ``m . x = e`` and the
   camera plane of a view are one plane, so ``n = R m`` (R by Kabsch on the normals, two non-parallel
   normals) and ``n . t = d - e`` (t by least squares, three independent normals);
2. nonlinear refinement of Zhang & Pless's point-to-plane cost, SciPy ``least_squares`` with a robust
   (soft L1) loss, every view weighted alike (a view's camera plane, not its number of points, carries
   its error);
3. the board points found again around the refined mount with a tighter window, and the refinement
   repeated.

Checks, each one line (:class:`CalibrationError`): at least three views with the board in both the
image and the cloud; the board normals spread in every direction (parallel boards leave the translation
along them unobserved); the final point-to-plane RMSE. Reported: the mount, its correction from the
nominal, the linear estimate, per-view RMSE before (nominal) and after, the normals' spread.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from lastmile.core.errors import CalibrationError, ConfigError, MessageError
from lastmile.localization.checkerboard_detection import (
    BoardView,
    Checkerboard,
    board_plane,
    plane_tangents,
)
from lastmile.localization.lidar_calibration import mount_difference
from lastmile.localization.lidar_planes import Plane, PlaneConfig, extract_planes


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraLidarConfig:
    """Parameters of the calibration.

    Attributes:
        search_margin_m: the board's LiDAR points are searched within this of where the nominal mount
            puts the board (in its plane and off it), m: 0.2 m and 2 degrees move a point 8 m away by
            0.48 m.
        refine_margin_m: the same around the refined mount, m (two 1-sigma noises of a 32-beam unit
            and the board's mixed edge returns).
        plane_distance_m: a point within this of the board plane is its inlier, m (three times the
            2-3 cm 1-sigma range noise of Velodyne VLP-32C / Ouster OS1 datasheets).
        max_angle_rad: the LiDAR plane taken for the board faces within this of the predicted board,
            rad (bounds the nominal rotation's error, with the PnP normal's).
        min_board_points: fewer LiDAR points on the board skip the view.
        min_views: views needed (three independent planes fix the translation).
        min_normal_spread_rad: the board normals' RMS tilt towards their least-covered direction must
            reach this, rad: the translation along it is held by that tilt, so a view's 1 cm plane
            error becomes 1 cm / sin(tilt) there (11.5 cm at 5 degrees).
        lidar_noise_m: the LiDAR's 1-sigma range noise, m, which whitens the point-to-plane residuals
            (2 cm: VLP-32C / OS1 datasheets' accuracy); soft L1 acts beyond two sigma.
        max_rmse_m: a final point-to-plane RMSE above this fails the calibration, m.
        camera_planes: also estimate each view's camera plane within its PnP covariance (False: fixed,
            as Zhang & Pless; see :func:`refine_mount`).
        seed: seed of the RANSAC sampler.
    """

    search_margin_m: float = 0.5
    refine_margin_m: float = 0.1
    plane_distance_m: float = 0.06
    max_angle_rad: float = math.radians(10.0)
    min_board_points: int = 30
    min_views: int = 3
    min_normal_spread_rad: float = math.radians(5.0)
    lidar_noise_m: float = 0.02
    max_rmse_m: float = 0.05
    camera_planes: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        for name in (
            "search_margin_m",
            "refine_margin_m",
            "plane_distance_m",
            "max_angle_rad",
            "min_normal_spread_rad",
            "lidar_noise_m",
            "max_rmse_m",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(f"CameraLidarConfig.{name}: expected a positive number, got {value!r}")
        if self.min_views < 3 or self.min_board_points < 3:
            raise ConfigError(
                "CameraLidarConfig: expected min_views >= 3 and min_board_points >= 3, got "
                f"{self.min_views} and {self.min_board_points}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class ViewFit:
    """One view's part in the calibration.

    Attributes:
        name: the view.
        board_points: LiDAR points on the board (final window).
        nominal_rmse_m: their RMS distance to the camera's board plane under the nominal mount, m
            (the first window's points).
        rmse_m: the same under the calibrated mount, m.
        reprojection_rmse_px: the PnP fit of the image's corners, px.
    """

    name: str
    board_points: int
    nominal_rmse_m: float
    rmse_m: float
    reprojection_rmse_px: float


@dataclass(frozen=True, slots=True, kw_only=True)
class SkippedView:
    """A view left out, and why (one line)."""

    name: str
    reason: str


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraLidarCalibration:
    """A calibrated LiDAR-to-camera mount.

    Attributes:
        camera_from_lidar: (4, 4) float64 the calibrated mount, LiDAR frame -> camera optical frame.
        nominal_camera_from_lidar: (4, 4) the mount it started from.
        linear_camera_from_lidar: (4, 4) the closed-form estimate (planes only, nominal window).
        correction_m: distance between the nominal and calibrated camera centres, m.
        correction_rad: angle of the rotation between them, rad.
        rmse_m: point-to-plane RMSE over all views' board points, m.
        normal_spread_rad: RMS tilt of the board normals towards their least-covered direction, rad.
        weakest_direction: (3,) that direction in the camera frame.
        views: the views used.
        skipped: the views left out, with their reasons.
    """

    camera_from_lidar: np.ndarray
    nominal_camera_from_lidar: np.ndarray
    linear_camera_from_lidar: np.ndarray
    correction_m: float
    correction_rad: float
    rmse_m: float
    normal_spread_rad: float
    weakest_direction: np.ndarray
    views: tuple[ViewFit, ...]
    skipped: tuple[SkippedView, ...]


@dataclass(frozen=True, slots=True)
class _BoardPoints:
    view: BoardView
    cloud: np.ndarray  # (N, 3) the view's whole cloud, LiDAR frame
    plane: Plane  # the LiDAR's board plane, in the LiDAR frame


def calibrate_camera_lidar(
    views: Sequence[tuple[BoardView, np.ndarray]],
    board: Checkerboard,
    nominal_camera_from_lidar: np.ndarray,
    config: CameraLidarConfig | None = None,
    skipped: Sequence[SkippedView] = (),
) -> CameraLidarCalibration:
    """The LiDAR-to-camera mount from views of a checkerboard.

    Args:
        views: each view's board as the camera saw it, and the LiDAR's (N, 3) cloud in its own frame, m.
        board: the checkerboard (its squares bound the LiDAR's search window).
        nominal_camera_from_lidar: (4, 4) the mount as designed or last calibrated.
        config: parameters.
        skipped: views already left out (the board not found in the image), reported with the others.

    Raises:
        MessageError: a cloud is not (N, 3) finite, or the nominal mount is not a rigid transform.
        CalibrationError: fewer than ``min_views`` usable views, board normals not spread in every
            direction, or a final RMSE above ``max_rmse_m``.
    """
    c = config or CameraLidarConfig()
    nominal = _rigid("nominal camera_from_lidar", nominal_camera_from_lidar)
    pairs = [(v, _cloud(v.name, cloud)) for v, cloud in views]
    left_out = list(skipped)
    found = _board_points(pairs, nominal, board, c.search_margin_m, c, left_out, "")
    _check_views(found, left_out, c)
    _check_spread([f.view.normal for f in found], c)
    linear = linear_mount(found)
    first = refine_mount(found, linear, c.lidar_noise_m, c.camera_planes)
    again = [(f.view, f.cloud) for f in found]
    used = _board_points(again, first, board, c.refine_margin_m, c, left_out, " (refined window)")
    _check_views(used, left_out, c)
    pose = refine_mount(used, first, c.lidar_noise_m, c.camera_planes)
    nominal_rmse = {f.view.name: _rmse(f, nominal) for f in found}
    fits = tuple(
        ViewFit(
            name=f.view.name,
            board_points=f.plane.inliers,
            nominal_rmse_m=nominal_rmse[f.view.name],
            rmse_m=_rmse(f, pose),
            reprojection_rmse_px=f.view.reprojection_rmse_px,
        )
        for f in used
    )
    residuals = np.concatenate([_residuals(f, pose) for f in used])
    rmse = float(np.sqrt(np.mean(residuals**2)))
    if rmse > c.max_rmse_m:
        raise CalibrationError(
            f"camera-LiDAR calibration: expected the LiDAR's board points within {c.max_rmse_m} m RMS of "
            f"the camera's board planes, got {rmse:.3f} m (a wrong board size, intrinsics or pairing)"
        )
    spread, weakest = normal_spread([f.view.normal for f in used])
    corr_m, corr_rad = mount_difference(np.linalg.inv(nominal), np.linalg.inv(pose))
    return CameraLidarCalibration(
        camera_from_lidar=pose,
        nominal_camera_from_lidar=nominal,
        linear_camera_from_lidar=linear,
        correction_m=corr_m,
        correction_rad=corr_rad,
        rmse_m=rmse,
        normal_spread_rad=spread,
        weakest_direction=weakest,
        views=fits,
        skipped=tuple(left_out),
    )


def linear_mount(views: Sequence[_BoardPoints]) -> np.ndarray:
    """Closed form from the planes: R by Kabsch on the normals (n = R m), t from n . t = d - e."""
    cam = np.array([v.view.normal for v in views])
    lid = np.array([v.plane.normal for v in views])
    u, _, vt = np.linalg.svd(lid.T @ cam)
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rot = vt.T @ fix @ u.T
    rhs = np.array([v.view.offset_m - v.plane.offset_m for v in views])
    t, *_ = np.linalg.lstsq(cam, rhs, rcond=None)
    pose = np.eye(4)
    pose[:3, :3] = rot
    pose[:3, 3] = t
    return pose


def refine_mount(
    views: Sequence[_BoardPoints], initial: np.ndarray, lidar_noise_m: float, camera_planes: bool = True
) -> np.ndarray:
    """Zhang & Pless's point-to-plane refinement from ``initial`` (soft L1 beyond two sigma).

    Each residual is taken along the point's ray, a range error: the LiDAR's noise lies along its rays,
    and the expected square of a perpendicular residual grows with ``(n . ray)^2``, which a rotation
    can shrink (a bias).

    With ``camera_planes`` (the default), each view's camera plane is estimated too, held to its PnP
    value by its covariance (:attr:`BoardView.plane_covariance`): Zhang & Pless fix the planes, and a
    plane's few-millimetre PnP offset error then turns the mount by its lever arm (0.1 degree for 5 mm
    at 3 m); here a plane moves where the LiDAR's points are firmer than the corners.
    """
    rot0 = initial[:3, :3]
    rotated0 = np.concatenate([v.plane.points for v in views]) @ rot0.T
    rays0 = rotated0 / np.linalg.norm(rotated0, axis=1, keepdims=True)
    sizes = [v.plane.points.shape[0] for v in views]
    view_of = np.repeat(np.arange(len(views)), sizes)
    base_n = np.array([v.view.normal for v in views])
    base_d = np.array([v.view.offset_m for v in views])
    tangents = np.array([plane_tangents(v.view.normal) for v in views])  # (V, 2, 3)
    whiten = np.array([np.linalg.inv(np.linalg.cholesky(_floored(v.view.plane_covariance))) for v in views])
    n_planes = 3 * len(views) if camera_planes else 0

    def residuals(x: np.ndarray) -> np.ndarray:
        delta = Rotation.from_rotvec(x[:3]).as_matrix()
        moved = rotated0 @ delta.T + x[3:6]
        theta = x[6:].reshape(-1, 3) if camera_planes else np.zeros((len(views), 3))
        normals = base_n + np.einsum("vk,vkj->vj", theta[:, :2], tangents)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        offsets = base_d + theta[:, 2]
        n = normals[view_of]
        incidence = np.maximum(np.abs(np.einsum("ij,ij->i", rays0 @ delta.T, n)), MIN_INCIDENCE)
        along = (np.einsum("ij,ij->i", moved, n) - offsets[view_of]) / incidence / lidar_noise_m
        if not camera_planes:
            return along
        return np.concatenate([along, np.einsum("vij,vj->vi", whiten, theta).ravel()])

    x0 = np.concatenate([np.zeros(3), initial[:3, 3], np.zeros(n_planes)])
    sparsity = _sparsity(view_of, len(views)) if camera_planes else None
    sol = least_squares(residuals, x0, loss="soft_l1", f_scale=2.0, x_scale="jac", jac_sparsity=sparsity)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(sol.x[:3]).as_matrix() @ rot0
    pose[:3, 3] = sol.x[3:6]
    return pose


def _sparsity(view_of: np.ndarray, n_views: int) -> sparse.lil_matrix:
    """Which parameters each residual depends on: the mount's six, and its own view's plane."""
    n_points = view_of.size
    out = sparse.lil_matrix((n_points + 3 * n_views, 6 + 3 * n_views), dtype=int)
    out[:n_points, :6] = 1
    for i in range(3):
        out[np.arange(n_points), 6 + 3 * view_of + i] = 1
    for v in range(n_views):
        out[n_points + 3 * v : n_points + 3 * v + 3, 6 + 3 * v : 9 + 3 * v] = 1
    return out


def _floored(cov: np.ndarray) -> np.ndarray:
    """A plane covariance with a floor (1e-5 rad, 10 um) that keeps its Cholesky factor finite."""
    return np.asarray(cov, dtype=np.float64) + np.diag([1e-10, 1e-10, 1e-10])


MIN_INCIDENCE = 0.2
"""Cosine of the steepest incidence (78 degrees) whose range residual is taken as is; grazing rays
beyond are weighted as at it (their range error is unbounded)."""


def ray_plane_fit(points: np.ndarray, normal: np.ndarray, offset_m: float) -> tuple[np.ndarray, float]:
    """The plane through a LiDAR's points (origin at the sensor) by their range residuals.

    A least-squares (SVD) plane assumes noise alike in every direction; a LiDAR's is along its rays,
    and the SVD plane of a board seen obliquely came out tilted by 0.15-0.4 degrees and 7 mm off (2 cm
    noise, 1000-2400 points). Starting from ``(normal, offset_m)``, this minimises
    ``(n . p - d) / |n . ray|``, the range error.
    """
    rays = points / np.linalg.norm(points, axis=1, keepdims=True)
    basis = plane_tangents(normal)

    def plane(x: np.ndarray) -> tuple[np.ndarray, float]:
        n = normal + x[0] * basis[0] + x[1] * basis[1]
        return n / np.linalg.norm(n), offset_m + x[2]

    def residuals(x: np.ndarray) -> np.ndarray:
        n, d = plane(x)
        return (points @ n - d) / np.maximum(np.abs(rays @ n), MIN_INCIDENCE)

    sol = least_squares(residuals, np.zeros(3), x_scale="jac")
    return plane(sol.x)


def normal_spread(normals: Sequence[np.ndarray]) -> tuple[float, np.ndarray]:
    """RMS tilt (rad) of unit normals towards their least-covered direction, and that direction (3,)."""
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    vals, vecs = np.linalg.eigh(n.T @ n / n.shape[0])
    return float(math.asin(math.sqrt(min(max(vals[0], 0.0), 1.0)))), vecs[:, 0]


def _board_points(
    views: Sequence[tuple[BoardView, np.ndarray]],
    camera_from_lidar: np.ndarray,
    board: Checkerboard,
    margin_m: float,
    c: CameraLidarConfig,
    left_out: list[SkippedView],
    note: str,
) -> list[_BoardPoints]:
    """Each view's LiDAR board plane near where ``camera_from_lidar`` puts the board; the views where
    none is found go to ``left_out`` with their reason (and ``note``)."""
    lidar_from_camera = np.linalg.inv(camera_from_lidar)
    out = []
    for view, cloud in views:
        try:
            plane = _board_plane(view, cloud, lidar_from_camera, board, margin_m, c)
        except CalibrationError as exc:
            left_out.append(SkippedView(name=view.name, reason=f"{exc}{note}"))
            continue
        out.append(_BoardPoints(view=view, cloud=cloud, plane=plane))
    return out


def _board_plane(
    view: BoardView,
    cloud: np.ndarray,
    lidar_from_camera: np.ndarray,
    board: Checkerboard,
    margin_m: float,
    c: CameraLidarConfig,
) -> Plane:
    lidar_from_board = lidar_from_camera @ view.camera_from_board
    rot, t = lidar_from_board[:3, :3], lidar_from_board[:3, 3]
    local = (cloud - t) @ rot
    x0, x1, y0, y1 = board.squares_extent_m()
    window = (
        (np.abs(local[:, 2]) <= margin_m)
        & (local[:, 0] >= x0 - margin_m)
        & (local[:, 0] <= x1 + margin_m)
        & (local[:, 1] >= y0 - margin_m)
        & (local[:, 1] <= y1 + margin_m)
    )
    near = cloud[window]
    if near.shape[0] < c.min_board_points:
        raise CalibrationError(
            f"expected at least {c.min_board_points} LiDAR points within {margin_m} m of the "
            f"board where the camera and the mount put it, got {near.shape[0]}"
        )
    config = PlaneConfig(
        distance_m=c.plane_distance_m, min_points=c.min_board_points, max_planes=3, seed=c.seed
    )
    predicted, _ = board_plane(lidar_from_board)
    facing = [
        p
        for p in extract_planes(near, np.zeros(3), config)
        if p.normal @ predicted >= math.cos(c.max_angle_rad)
    ]
    if not facing:
        raise CalibrationError(
            f"expected a plane of at least {c.min_board_points} LiDAR points facing within "
            f"{math.degrees(c.max_angle_rad):.0f} deg of the board near it, got none among "
            f"{near.shape[0]} points"
        )
    best = max(facing, key=lambda p: p.inliers)
    normal, offset = ray_plane_fit(best.points, best.normal, best.offset_m)
    return dataclasses.replace(best, normal=normal, offset_m=offset)


def _check_views(
    found: Sequence[_BoardPoints], left_out: Sequence[SkippedView], c: CameraLidarConfig
) -> None:
    if len(found) >= c.min_views:
        return
    why = "; ".join(f"{s.name}: {s.reason}" for s in left_out[:3])
    more = f" (+{len(left_out) - 3} more)" if len(left_out) > 3 else ""
    raise CalibrationError(
        f"camera-LiDAR calibration: expected at least {c.min_views} views with the board found in both the "
        f"image and the cloud, got {len(found)}" + (f"; skipped {why}{more}" if why else "")
    )


def _check_spread(normals: Sequence[np.ndarray], c: CameraLidarConfig) -> None:
    spread, weakest = normal_spread(normals)
    if spread < c.min_normal_spread_rad:
        axis = ", ".join(f"{v:+.2f}" for v in weakest)
        raise CalibrationError(
            f"camera-LiDAR calibration: expected the board normals to tilt at least "
            f"{math.degrees(c.min_normal_spread_rad):.1f} deg RMS towards every direction, got "
            f"{math.degrees(spread):.2f} deg towards ({axis}) in the camera frame (boards nearly parallel: "
            "turn and tilt the board between views)"
        )


def _residuals(view: _BoardPoints, camera_from_lidar: np.ndarray) -> np.ndarray:
    moved = view.plane.points @ camera_from_lidar[:3, :3].T + camera_from_lidar[:3, 3]
    return moved @ view.view.normal - view.view.offset_m


def _rmse(view: _BoardPoints, camera_from_lidar: np.ndarray) -> float:
    return float(np.sqrt(np.mean(_residuals(view, camera_from_lidar) ** 2)))


def _cloud(name: str, cloud: np.ndarray) -> np.ndarray:
    arr = np.asarray(cloud, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise MessageError(f"{name}: expected an (N, 3) LiDAR cloud, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise MessageError(f"{name}: expected finite LiDAR points, got NaN/inf")
    return arr


def _rigid(what: str, pose: np.ndarray) -> np.ndarray:
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape != (4, 4) or not np.isfinite(arr).all():
        raise MessageError(f"{what}: expected a finite (4, 4) transform, got shape {arr.shape}")
    rot = arr[:3, :3]
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or abs(np.linalg.det(rot) - 1.0) > 1e-6:
        raise MessageError(
            f"{what}: expected a rotation in the upper-left 3x3, got det {np.linalg.det(rot):.6f}"
        )
    return arr
