"""Snow Lion scan-to-map matching: a LiDAR sweep registered to a downsampled point-cloud map (small_gicp).

Snow Lion ("Localization"): downsample the map built by mapping, take the region of interest around the
pose predicted by the filter, register the scan to it with ICP, and fuse the pose in an EKF that
tolerates delayed scans. Here the map is downsampled once and indexed by a k-d tree, so the region of
interest is what the tree returns within ``max_correspondence_m`` of the scan placed at the predicted
pose (no per-scan crop and rebuild); the scan itself is cropped to ``roi_radius_m``. Registration is
small_gicp's point-to-plane ICP (or GICP), which ``benchmarks/scan_matching_speed.py`` compares with a
SciPy point-to-plane ICP. The result carries a covariance: the Gauss-Newton information of the final
iteration scaled by the residual variance, plus the map's own accuracy; the confidence is derived from
it, so a degenerate scene (a straight corridor of walls, where the along-track position is not
constrained) reports itself as such instead of returning a confident wrong pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np

from lastmile.core.errors import ConfigError, MessageError


class Registration(Enum):
    """Registration cost: point-to-plane ICP (Snow Lion) or generalized ICP."""

    PLANE_ICP = "PLANE_ICP"
    GICP = "GICP"


@dataclass(frozen=True, slots=True, kw_only=True)
class ScanMatchConfig:
    """Parameters of :class:`ScanToMapMatcher`.

    Attributes:
        map_voxel_m: voxel size the map is downsampled to, m.
        scan_voxel_m: voxel size each scan is downsampled to, m.
        roi_radius_m: scan points farther than this from the sensor are dropped, m.
        max_correspondence_m: largest point-to-map distance paired in an iteration, m (bounds how far
            off the predicted pose may be).
        max_iterations: Gauss-Newton iterations.
        neighbours: points used for each normal / covariance estimate.
        registration: cost function.
        map_accuracy_std_m: one-sigma accuracy of the map itself (a GNSS-constrained map: RTK level), m;
            added to the formal position covariance, which only knows the scan's own residuals.
        map_accuracy_std_rad: the same for heading, rad.
        min_inlier_share: fewer scan points paired than this share means the scan does not match the map.
        min_constraint_share: a horizontal direction is constrained when the pairs' squared normal
            components along it sum to at least this share of the pairs (1 %: as if 1 % of the points
            lay on a surface facing it; normal noise of a few degrees gives 0.1-0.3 %).
        max_pos_std_m: the match is confident while its position sigma (largest horizontal axis) is
            within this, m.
        max_yaw_std_rad: and its heading sigma within this, rad.
        max_scan_points: the downsampled scan is thinned to at most this many points (evenly through
            the cloud, deterministic): a rig frame of three LiDARs leaves 8-14k points at 0.25-0.5 m
            voxels, and the nearest-neighbour search per point and iteration is what costs; 2000 keeps
            a registration near 7 ms on one core (``benchmarks/localization_modes.py``). 0: no limit.
    """

    map_voxel_m: float = 0.25
    scan_voxel_m: float = 0.25
    roi_radius_m: float = 60.0
    max_correspondence_m: float = 1.0
    max_iterations: int = 30
    neighbours: int = 10
    registration: Registration = Registration.PLANE_ICP
    map_accuracy_std_m: float = 0.02
    map_accuracy_std_rad: float = 0.002
    min_inlier_share: float = 0.5
    min_constraint_share: float = 0.01
    max_pos_std_m: float = 0.1
    max_yaw_std_rad: float = 0.01
    max_scan_points: int = 2000

    def __post_init__(self) -> None:
        for name in (
            "map_voxel_m",
            "scan_voxel_m",
            "roi_radius_m",
            "max_correspondence_m",
            "map_accuracy_std_m",
            "map_accuracy_std_rad",
            "max_pos_std_m",
            "max_yaw_std_rad",
            "min_constraint_share",
        ):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"ScanMatchConfig.{name}: expected a positive number, got {value!r}")
        if self.max_scan_points != 0 and self.max_scan_points < 100:
            raise ConfigError(
                "ScanMatchConfig.max_scan_points: expected 0 (no limit) or >= 100, "
                f"got {self.max_scan_points}"
            )
        if self.max_iterations < 1 or self.neighbours < 5:
            raise ConfigError(
                "ScanMatchConfig: expected max_iterations >= 1 and neighbours >= 5, "
                f"got {self.max_iterations} and {self.neighbours}"
            )
        if not 0.0 < self.min_inlier_share <= 1.0:
            raise ConfigError(
                f"ScanMatchConfig.min_inlier_share: expected (0, 1], got {self.min_inlier_share}"
            )
        if not isinstance(self.registration, Registration):
            raise ConfigError(
                f"ScanMatchConfig.registration: expected a Registration, got {self.registration!r}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class ScanMatch:
    """The result of one registration.

    Attributes:
        map_from_sensor: (4, 4) float64 pose of the sensor in the map frame.
        x_m, y_m, yaw_rad: its planar part.
        covariance: (3, 3) float64 covariance of (x_m, y_m, yaw_rad).
        pos_std_m: sigma of position along its worst horizontal axis, m.
        yaw_std_rad: heading sigma, rad.
        inlier_share: share of the (downsampled) scan points paired with the map.
        rmse_m: root-mean-square point-to-plane residual of the pairs, m.
        iterations: Gauss-Newton iterations run.
        converged: the registration met its convergence test.
        confident: converged, enough inliers and both sigmas within the configured bounds.
    """

    map_from_sensor: np.ndarray
    x_m: float
    y_m: float
    yaw_rad: float
    covariance: np.ndarray
    pos_std_m: float
    yaw_std_rad: float
    inlier_share: float
    rmse_m: float
    iterations: int
    converged: bool
    confident: bool


class ScanToMapMatcher:
    """Registers LiDAR sweeps to a point-cloud map; the map is preprocessed once."""

    def __init__(self, map_points: np.ndarray, config: ScanMatchConfig | None = None) -> None:
        """Downsample the map, estimate its normals and covariances, index it.

        Args:
            map_points: (N, 3) float map points in the map frame, m.

        Raises:
            MessageError: a map that is not (N, 3), has fewer than 100 points or non-finite values.
        """
        import small_gicp

        self.config = c = config or ScanMatchConfig()
        points = _check_points("map_points", map_points, 100)
        self._small_gicp = small_gicp
        self._map, self._tree = small_gicp.preprocess_points(
            points, downsampling_resolution=c.map_voxel_m, num_neighbors=c.neighbours
        )

    @property
    def map_size(self) -> int:
        """Points in the downsampled map."""
        return int(self._map.size())

    def match(self, scan_points: np.ndarray, predicted_map_from_sensor: np.ndarray) -> ScanMatch:
        """Register one sweep, starting from the predicted pose.

        Args:
            scan_points: (M, 3) float points in the sensor frame (motion-compensated), m.
            predicted_map_from_sensor: (4, 4) float the predicted pose of the sensor.

        Raises:
            MessageError: bad shapes, non-finite values, fewer than 30 points within the region of
                interest.
        """
        c = self.config
        points = _check_points("scan_points", scan_points, 30)
        init = np.asarray(predicted_map_from_sensor, dtype=np.float64)
        if init.shape != (4, 4) or not np.isfinite(init).all():
            raise MessageError(
                f"predicted_map_from_sensor: expected a finite (4, 4) pose, got shape {init.shape}"
            )
        near = points[np.einsum("ij,ij->i", points[:, :2], points[:, :2]) <= c.roi_radius_m**2]
        if near.shape[0] < 30:
            raise MessageError(
                f"scan_points: expected at least 30 points within {c.roi_radius_m} m, got {near.shape[0]}"
            )
        sg = self._small_gicp
        scan = self._scan_cloud(near)
        result = sg.align(
            self._map,
            scan,
            self._tree,
            init_T_target_source=init,
            registration_type=c.registration.value,
            max_correspondence_distance=c.max_correspondence_m,
            max_iterations=c.max_iterations,
        )
        return self._result(result, int(scan.size()))

    def _scan_cloud(self, near: np.ndarray) -> Any:
        """The scan downsampled (and thinned to ``max_scan_points``) as small_gicp wants it: point-to-plane
        ICP uses only the map's normals, so the scan's are estimated for GICP alone."""
        c, sg = self.config, self._small_gicp
        down = np.asarray(sg.voxelgrid_sampling(near, c.scan_voxel_m).points())
        if c.max_scan_points and down.shape[0] > c.max_scan_points:
            down = down[np.linspace(0, down.shape[0] - 1, c.max_scan_points).astype(np.int64)]
        if c.registration is Registration.GICP:
            scan, _ = sg.preprocess_points(
                down[:, :3], downsampling_resolution=c.scan_voxel_m, num_neighbors=c.neighbours
            )
            return scan
        return sg.PointCloud(np.ascontiguousarray(down[:, :3]))

    def _degeneracy(self, info: np.ndarray, inliers: int, local: np.ndarray) -> np.ndarray:
        """Open up the covariance along directions no surface constrains (Zhang et al., ICRA 2016).

        The point-to-plane information along a direction is the sum over pairs of the squared normal
        component along it. Along a straight corridor of walls that is only noise in the normals, and
        the formal covariance (residual variance over that information) claims millimetres. A direction
        whose information is below ``min_constraint_share`` of the pairs (as if fewer than that share
        of the points lay on surfaces facing it) is unconstrained: its variance becomes the square of
        ``max_correspondence_m``, the farthest the registration could have moved along it.
        """
        c = self.config
        weak = _unconstrained(info, inliers, c.min_constraint_share)
        if not weak or not np.isfinite(local).all():
            return local
        out = local.copy()
        for v in weak:
            out[:2, :2] += c.max_correspondence_m**2 * np.outer(v, v)
        return out

    def _result(self, result: object, scan_size: int) -> ScanMatch:
        c = self.config
        pose = np.array(result.T_target_source, dtype=np.float64)  # type: ignore[attr-defined]
        inliers = int(result.num_inliers)  # type: ignore[attr-defined]
        error = float(result.error)  # type: ignore[attr-defined]
        # small_gicp minimises 0.5 * sum(r^2) and returns the Gauss-Newton information H (rotation first,
        # then translation, in the pose's local frame); the pose covariance is sigma^2 H^-1.
        sigma2 = 2.0 * error / max(inliers - 6, 1)
        info = np.array(result.H, dtype=np.float64)  # type: ignore[attr-defined]
        # x, y (translation 3, 4) and yaw (rotation 2), rotated into the map frame.
        rows = [3, 4, 2]
        try:
            local = sigma2 * np.linalg.inv(info)[np.ix_(rows, rows)]
        except np.linalg.LinAlgError:
            local = np.diag([math.inf, math.inf, math.inf])
        local = self._degeneracy(info, inliers, local)
        yaw = math.atan2(pose[1, 0], pose[0, 0])
        rot = np.eye(3)
        rot[:2, :2] = pose[:2, :2] if np.isfinite(local).all() else np.eye(2)
        cov = rot @ local @ rot.T if np.isfinite(local).all() else local
        cov = cov + np.diag([c.map_accuracy_std_m**2, c.map_accuracy_std_m**2, c.map_accuracy_std_rad**2])
        xy = cov[:2, :2]
        pos_std = (
            math.sqrt(max(float(np.linalg.eigvalsh(xy)[-1]), 0.0)) if np.isfinite(xy).all() else math.inf
        )
        yaw_std = math.sqrt(cov[2, 2]) if math.isfinite(cov[2, 2]) else math.inf
        share = inliers / max(scan_size, 1)
        converged = bool(result.converged)  # type: ignore[attr-defined]
        confident = (
            converged
            and share >= c.min_inlier_share
            and pos_std <= c.max_pos_std_m
            and yaw_std <= c.max_yaw_std_rad
        )
        return ScanMatch(
            map_from_sensor=pose,
            x_m=float(pose[0, 3]),
            y_m=float(pose[1, 3]),
            yaw_rad=yaw,
            covariance=cov,
            pos_std_m=pos_std,
            yaw_std_rad=yaw_std,
            inlier_share=share,
            rmse_m=math.sqrt(sigma2),
            iterations=int(result.iterations),  # type: ignore[attr-defined]
            converged=converged,
            confident=confident,
        )


def _unconstrained(info: np.ndarray, inliers: int, min_share: float) -> list[np.ndarray]:
    """Horizontal directions (unit (2,) vectors in the sensor frame) the scan's surfaces do not constrain."""
    vals, vecs = np.linalg.eigh(info[3:5, 3:5])
    return [vecs[:, i] for i in range(2) if vals[i] < min_share * max(inliers, 1)]


def _check_points(what: str, points: np.ndarray, minimum: int) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < minimum:
        raise MessageError(f"{what}: expected an (N, 3) array with N >= {minimum}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise MessageError(f"{what}: expected finite coordinates, got NaN or inf")
    return arr
