"""Snow Lion's scan-matching localization mode: its settings and the match as a gated pose measurement.

A scan-to-map match (:mod:`lastmile.localization.scan_matching`) is a measurement of the base pose with
the matcher's own covariance. Before it reaches the EKF it must pass the match's quality limits
(converged, enough of the scan paired with the map, point-to-plane RMSE within ``max_rmse_m``); the EKF
then gates it at its 0.999 chi-square quantile (Mahalanobis distance of the innovation). Directions the
scene does not constrain (a straight street between parallel walls leaves the along-track position
free: the matcher opens its covariance there) are not fused at all: the measurement is projected onto
the horizontal directions whose sigma is within ``max_direction_std_m`` (and the heading, when its sigma
is within ``max_yaw_std_rad``), so a degenerate match corrects only what it measures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import wrap_angle_rad
from lastmile.core.stamp import Stamp
from lastmile.localization.landmark_localization import Linearised
from lastmile.localization.point_cloud_map import read_point_cloud_map
from lastmile.localization.scan_matching import ScanMatch, ScanMatchConfig


@dataclass(frozen=True, slots=True, kw_only=True)
class ScanMatchingSettings:
    """``[stack.scan_matching]``: the map and the matcher of the ``scan_matching`` localization mode.

    Attributes:
        map: the point-cloud map (PCD, from ``lastmile map build``), a path.
        max_rmse_m: a match leaving a larger point-to-plane RMSE is not fused, m (the LiDAR's 3 cm
            range noise and the map's 0.2 m voxels give about 2 cm on a good match).
        max_direction_std_m: a horizontal direction whose match sigma exceeds this is not fused, m.
        max_yaw_std_rad: nor the heading when its sigma exceeds this, rad.
        matcher: the registration's parameters (``[stack.scan_matching.matcher]``).
    """

    map: str = ""
    max_rmse_m: float = 0.1
    max_direction_std_m: float = 0.1
    max_yaw_std_rad: float = 0.01
    matcher: ScanMatchConfig = field(default_factory=ScanMatchConfig)

    def __post_init__(self) -> None:
        for name in ("max_rmse_m", "max_direction_std_m", "max_yaw_std_rad"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"stack.scan_matching.{name}: expected a positive number, got {value!r}")

    def load_map(self) -> np.ndarray:
        """The map's points; one line (a ``ConfigError`` naming the key) when none is given or it is bad."""
        if not self.map:
            raise ConfigError(
                "stack.scan_matching.map: expected the point-cloud map (a .pcd from `lastmile map build`), "
                "got none"
            )
        try:
            return read_point_cloud_map(self.map)
        except Exception as exc:  # MapError and anything a broken file raises: one line
            raise ConfigError(f"stack.scan_matching.map: {exc}") from None


@dataclass(frozen=True, slots=True, kw_only=True)
class ScanMatchMeasurement:
    """A scan-to-map match of the base pose, fused only along the directions it constrains.

    Attributes:
        stamp: the scan's capture time.
        x_m, y_m, yaw_rad: the matched base pose in the map frame.
        covariance: (3, 3) its covariance (x_m, y_m, yaw_rad).
        max_direction_std_m: horizontal directions with a larger sigma are not fused, m.
        max_yaw_std_rad: the heading is not fused with a larger sigma, rad.
    """

    stamp: Stamp
    x_m: float
    y_m: float
    yaw_rad: float
    covariance: np.ndarray
    max_direction_std_m: float
    max_yaw_std_rad: float

    def rows(self) -> np.ndarray:
        """(m, 3) the fused directions over (x, y, yaw): constrained horizontal axes, then the heading."""
        cov = np.asarray(self.covariance, dtype=float)
        if cov.shape != (3, 3) or not np.isfinite(cov).all():
            return np.zeros((0, 3))
        vals, vecs = np.linalg.eigh(cov[:2, :2])
        out = [
            np.array([vecs[0, i], vecs[1, i], 0.0])
            for i in range(2)
            if vals[i] <= self.max_direction_std_m**2
        ]
        if cov[2, 2] <= self.max_yaw_std_rad**2:
            out.append(np.array([0.0, 0.0, 1.0]))
        return np.array(out).reshape(-1, 3)

    def linearize(self, pose: np.ndarray, covariance: np.ndarray) -> Linearised | None:
        p = self.rows()
        if p.shape[0] == 0:
            return None
        full = np.array([self.x_m - pose[0], self.y_m - pose[1], wrap_angle_rad(self.yaw_rad - pose[2])])
        return p @ full, p, p @ np.asarray(self.covariance, dtype=float) @ p.T


def measurement(
    match: ScanMatch, stamp: Stamp, settings: ScanMatchingSettings
) -> ScanMatchMeasurement | None:
    """The match as a measurement, or None when it fails the quality limits (not converged, too few
    of the scan's points paired with the map, RMSE over ``max_rmse_m``)."""
    if not match.converged or match.inlier_share < settings.matcher.min_inlier_share:
        return None
    if not match.rmse_m <= settings.max_rmse_m:
        return None
    return ScanMatchMeasurement(
        stamp=stamp,
        x_m=match.x_m,
        y_m=match.y_m,
        yaw_rad=match.yaw_rad,
        covariance=match.covariance,
        max_direction_std_m=settings.max_direction_std_m,
        max_yaw_std_rad=settings.max_yaw_std_rad,
    )
