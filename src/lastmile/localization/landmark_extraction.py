"""Pole and facade detections from a LiDAR cloud's clusters, with covariances from the LiDAR's noise.

WATonoBus (III-B 2) localizes without GNSS on large georeferenced landmarks: light poles and building
planes. Here they are found among the clusters of the perception's non-ground points (base frame):

- a **pole** is a tall, thin, vertical cluster that stands on the ground: its footprint is at most
  ``pole_max_diameter_m`` across (EN 40 lighting columns up to 12 m have bases of about 0.1-0.3 m), it
  rises at least ``pole_min_height_m`` (lighting columns are at least 3 m tall; the crop of the LiDAR
  chain may cut the top, people and car roofs stay below 2.5 m) and its lowest return is within
  ``pole_base_max_z_m`` of the ground (a sign plate or a branch hangs higher). The LiDAR sees the near
  half of the column: the mean of its returns lies ``r pi/4`` short of the axis along the ray (points
  uniform in the sensor's azimuth over a half circle of radius r), with r read from the returns' spread
  across the ray (uniform over the chord: std = r / sqrt(3)).
- a **facade** is a straight vertical plane: a cluster at least ``facade_min_height_m`` high whose
  returns, binned on a ``facade_cell_m`` grid, hold a line (sequential RANSAC with a fixed sample order,
  then a total-least-squares fit) spanning at least ``facade_min_length_m``.

Each detection's covariance comes from the LiDAR's datasheet noise (``range_std_m``, the azimuth step's
quantisation) and the fit's own residuals, floored at ``map_accuracy_m`` (the surveyed landmark's own
error, which no number of returns averages away). The result feeds
:class:`~lastmile.localization.landmark_localization.PoleDetections` and ``FacadeDetections``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.config import check_range
from lastmile.core.errors import MessageError


@dataclass(frozen=True, slots=True, kw_only=True)
class LandmarkExtractionConfig:
    """Attributes (defaults from datasheets and standards, not fitted to a drive):
    range_std_m: LiDAR range noise, one sigma (Ouster OS1 / Velodyne VLP-32C datasheets: 1.5-3 cm).
    azimuth_step_deg: the LiDAR's column spacing (Velodyne VLP-32C at 10 Hz: 0.2 deg; set it to your
        unit's); the angle of a return is quantised to it.
    pole_max_diameter_m: largest horizontal extent of a pole's returns (EN 40 column bases, 0.3 m,
        plus a column of range noise and beam width on each side).
    pole_min_height_m: smallest vertical extent of a pole's returns.
    pole_base_max_z_m: a pole's lowest return is at most this high in the base frame (on the ground).
    pole_radius_range_m: plausible column radii (EN 40: 30-150 mm); the radius read from the spread is
        clipped to it.
    pole_min_points: returns a pole needs for a centre worth fusing.
    facade_min_height_m, facade_min_length_m: smallest plane worth fusing (a storey, a building side;
        smaller walls are fences and hedges the map does not hold).
    facade_cell_m: grid of the facade's returns in the plane (cell means).
    facade_inlier_m: RANSAC inlier distance (three range sigmas and a wall's unevenness).
    facade_max_rms_m: a plane whose cells scatter more than this about the line is not a wall.
    map_accuracy_m: one-sigma error of the surveyed landmark positions (a survey-grade HD map, 5 cm).
    max_range_m: detections beyond are not used (the azimuth quantisation grows with range).
    """

    range_std_m: float = 0.03
    azimuth_step_deg: float = 0.2
    pole_max_diameter_m: float = 0.6
    pole_min_height_m: float = 2.5
    pole_base_max_z_m: float = 1.0
    pole_radius_range_m: tuple[float, float] = (0.03, 0.15)
    pole_min_points: int = 8
    facade_min_height_m: float = 2.0
    facade_min_length_m: float = 5.0
    facade_cell_m: float = 0.25
    facade_inlier_m: float = 0.15
    facade_max_rms_m: float = 0.08
    map_accuracy_m: float = 0.05
    max_range_m: float = 40.0

    def __post_init__(self) -> None:
        check_range("landmarks.range_std_m", self.range_std_m, 1e-4, 0.5)
        check_range("landmarks.azimuth_step_deg", self.azimuth_step_deg, 0.01, 5.0)
        check_range("landmarks.pole_max_diameter_m", self.pole_max_diameter_m, 0.05, 2.0)
        check_range("landmarks.pole_min_height_m", self.pole_min_height_m, 0.5, 20.0)
        check_range("landmarks.pole_base_max_z_m", self.pole_base_max_z_m, 0.0, 5.0)
        lo, hi = self.pole_radius_range_m
        check_range("landmarks.pole_radius_range_m[0]", lo, 0.0, 1.0)
        check_range("landmarks.pole_radius_range_m[1]", hi, lo, 1.0)
        check_range("landmarks.pole_min_points", self.pole_min_points, 3, 10_000)
        check_range("landmarks.facade_min_height_m", self.facade_min_height_m, 0.5, 50.0)
        check_range("landmarks.facade_min_length_m", self.facade_min_length_m, 1.0, 200.0)
        check_range("landmarks.facade_cell_m", self.facade_cell_m, 0.05, 2.0)
        check_range("landmarks.facade_inlier_m", self.facade_inlier_m, 0.01, 1.0)
        check_range("landmarks.facade_max_rms_m", self.facade_max_rms_m, 0.005, 1.0)
        check_range("landmarks.map_accuracy_m", self.map_accuracy_m, 0.0, 2.0)
        check_range("landmarks.max_range_m", self.max_range_m, 1.0, 200.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class ExtractedLandmarks:
    """Poles and facade lines found in one cloud (base frame).

    Attributes:
        pole_xy_m: (k, 2) pole axis positions.
        pole_std_m: (k,) one-sigma error of each, per axis.
        facade_lines: (j, 2) distance from the base origin (m, > 0) and angle of the normal from the
            base towards the plane (rad).
        facade_distance_std_m, facade_angle_std_rad: (j,) one-sigma errors of each line.
    """

    pole_xy_m: np.ndarray
    pole_std_m: np.ndarray
    facade_lines: np.ndarray
    facade_distance_std_m: np.ndarray
    facade_angle_std_rad: np.ndarray


def extract_landmarks(
    xyz_m: np.ndarray, labels: np.ndarray, config: LandmarkExtractionConfig
) -> ExtractedLandmarks:
    """Poles and facades among the clusters of a cloud.

    Args:
        xyz_m: (N, 3) points in the base frame (z up from the ground under the base).
        labels: (N,) cluster label per point, < 0 for points in no cluster (ground, noise).
        config: limits and the LiDAR's noise.

    Raises:
        MessageError: arrays of the wrong shape or non-finite points.
    """
    xyz = np.asarray(xyz_m, dtype=np.float64)
    lab = np.asarray(labels)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or lab.shape != (len(xyz),):
        raise MessageError(
            f"extract_landmarks: expected (N, 3) points and (N,) labels, got {xyz.shape} and {lab.shape}"
        )
    keep = np.flatnonzero(lab >= 0)
    poles: list[tuple[float, float, float]] = []
    lines: list[tuple[float, float, float, float]] = []
    if len(keep):
        order = keep[np.argsort(lab[keep], kind="stable")]
        pts = xyz[order]
        if not np.isfinite(pts).all():
            raise MessageError("extract_landmarks: expected finite points, got NaN or inf")
        sorted_lab = lab[order]
        starts = np.flatnonzero(np.r_[True, sorted_lab[1:] != sorted_lab[:-1]])
        ends = np.r_[starts[1:], len(pts)]
        lo = np.minimum.reduceat(pts, starts, axis=0)
        hi = np.maximum.reduceat(pts, starts, axis=0)
        height = hi[:, 2] - lo[:, 2]
        extent = np.hypot(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1])
        c = config
        pole_like = (extent <= c.pole_max_diameter_m) & (height >= c.pole_min_height_m)
        pole_like &= (lo[:, 2] <= c.pole_base_max_z_m) & (ends - starts >= c.pole_min_points)
        for k in np.flatnonzero(pole_like):
            pole = _pole(pts[starts[k] : ends[k]], c)
            if pole is not None:
                poles.append(pole)
        wall_like = (height >= c.facade_min_height_m) & (extent >= c.facade_min_length_m)
        for k in np.flatnonzero(wall_like):
            lines.extend(_facade_lines(pts[starts[k] : ends[k], :2], c))
    p = np.array(poles, dtype=np.float64).reshape(-1, 3)
    f = np.array(lines, dtype=np.float64).reshape(-1, 4)
    return ExtractedLandmarks(
        pole_xy_m=p[:, :2].copy(),
        pole_std_m=p[:, 2].copy(),
        facade_lines=f[:, :2].copy(),
        facade_distance_std_m=f[:, 2].copy(),
        facade_angle_std_rad=f[:, 3].copy(),
    )


def _pole(pts: np.ndarray, c: LandmarkExtractionConfig) -> tuple[float, float, float] | None:
    """The axis of a pole cluster and its one-sigma error per axis; None beyond range."""
    xy = pts[:, :2]
    mean = xy.mean(axis=0)
    rng = float(np.hypot(*mean))
    if rng > c.max_range_m or rng < 1e-3:
        return None
    ray = mean / rng
    across = xy @ np.array([-ray[1], ray[0]])
    n = len(xy)
    step_m = rng * math.radians(c.azimuth_step_deg)
    # Radius from the extent across the ray (each outermost column lies uniformly within one step
    # inside its edge), clipped to the standard's column radii.
    r_lo, r_hi = c.pole_radius_range_m
    radius = float(np.clip((float(across.max() - across.min()) + step_m) / 2.0, r_lo, r_hi))
    centre = mean + ray * radius * math.pi / 4.0
    az_std_m = step_m / math.sqrt(12.0)
    # Along the ray: range noise averaged over the returns, and the radius's error (the two edge
    # columns' quantisation, each step/sqrt(12)) times pi/4. Across: the quantisation of the columns.
    radial_var = c.range_std_m**2 / n + (az_std_m / math.sqrt(2.0) * math.pi / 4.0) ** 2
    tangential_var = az_std_m**2 / 2.0
    std = math.sqrt(max(radial_var, tangential_var) + c.map_accuracy_m**2)
    return float(centre[0]), float(centre[1]), std


def _cells(xy: np.ndarray, cell_m: float) -> np.ndarray:
    """Mean of the returns in each occupied grid cell (a wall's columns of returns become one point)."""
    ij = np.floor(xy / cell_m).astype(np.int64)
    ij -= ij.min(axis=0)
    # One integer key per cell: np.unique on rows (axis=0) is several times slower.
    key = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    sums = np.column_stack([np.bincount(inverse, weights=xy[:, k]) for k in (0, 1)])
    return sums / counts[:, None]


def _facade_lines(xy: np.ndarray, c: LandmarkExtractionConfig) -> list[tuple[float, float, float, float]]:
    """Up to two walls of a building cluster (a corner shows two) as (rho, alpha, std rho, std alpha)."""
    cells = _cells(xy, c.facade_cell_m)
    min_cells = max(int(c.facade_min_length_m / c.facade_cell_m / 2), 5)
    out: list[tuple[float, float, float, float]] = []
    for _ in range(2):
        if len(cells) < min_cells:
            break
        inliers = _ransac_line(cells, c.facade_inlier_m)
        if inliers.sum() < min_cells:
            break
        line = _fit_line(cells[inliers], c)
        cells = cells[~inliers]
        if line is not None:
            out.append(line)
    return out


def _ransac_line(pts: np.ndarray, tol_m: float, trials: int = 40) -> np.ndarray:
    """Inlier mask of the line through two of ``pts`` that holds the most (pairs in a fixed order)."""
    n = len(pts)
    # Pairs spread along the cloud give well-conditioned lines; fixed strides keep it repeatable.
    order = np.argsort(pts[:, 0] + 1e-3 * pts[:, 1])
    t = np.arange(trials)
    a = pts[order[(t * 7919) % n]]
    b = pts[order[(t * 104729 + n // 2) % n]]
    d = b - a
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length >= 1.0
    if not ok.any():
        return np.zeros(n, dtype=bool)
    a, d, length = a[ok], d[ok], length[ok]
    normal = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    # (trials, n) distances of every point to every candidate line.
    dist = np.abs(pts @ normal.T - np.einsum("ij,ij->i", a, normal)).T
    inliers = dist <= tol_m
    return inliers[int(np.argmax(inliers.sum(axis=1)))]


def _fit_line(pts: np.ndarray, c: LandmarkExtractionConfig) -> tuple[float, float, float, float] | None:
    """Total least squares line of ``pts``: (rho, alpha) with its one-sigma errors; None if not a wall."""
    centroid = pts.mean(axis=0)
    centred = pts - centroid
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    direction, normal = vt[0], vt[1]
    t = centred @ direction
    span = float(t.max() - t.min())
    n = len(pts)
    rms = float(s[1]) / math.sqrt(n)
    if span < c.facade_min_length_m or rms > c.facade_max_rms_m:
        return None
    rho = float(normal @ centroid)
    if rho < 0:
        normal, rho = -normal, -rho
    if rho < 0.5 or rho > c.max_range_m:
        return None
    sigma = max(rms, c.range_std_m)
    # Line-fit errors: the offset at the centroid sigma/sqrt(n), the angle sigma/(sqrt(n) std(t));
    # the distance at the base origin also moves with the angle, by the lever arm to the centroid.
    # The surveyed wall's own direction is known to the map's accuracy over its half length.
    angle_std = math.hypot(
        sigma / (math.sqrt(n) * max(float(np.std(t)), 1e-3)), c.map_accuracy_m / max(span / 2.0, 1.0)
    )
    lever = float(centroid @ direction)
    rho_std = math.sqrt(sigma**2 / n + (lever * angle_std) ** 2 + c.map_accuracy_m**2)
    alpha = math.atan2(normal[1], normal[0])
    return rho, alpha, rho_std, angle_std
