"""WATonoBus GNSS-denied localization: LiDAR detections of the map's poles and facades as pose measurements.

WATonoBus (III-B 2): with GNSS degraded or lost, detections of large georeferenced landmarks near the
current s-coordinate (light poles, building planes; curbs) are associated with the HD map's landmark
records and fused with odometry, to keep a pose good enough for a safe stop or to drive on. Here each
kind of detection is a :class:`PoseMeasurement` that the pose EKF (``PoseEkf.update_pose``) linearises at
its own predicted pose, so late detections are inserted at their stamp like any input:

- :class:`PoleDetections`: pole centres in the base frame; each is associated with the nearest mapped
  pole by Mahalanobis distance (pose and detection uncertainty), and only when unambiguous (the second
  candidate is more than ``ambiguity_ratio`` farther), then measures the pose through the point.
- :class:`FacadeDetections`: building planes as lines in the base frame (distance and normal angle); each
  is associated with a mapped facade segment the same way and measures the pose's distance to it and its
  heading (a single facade leaves the position along it free, as it should).
- :class:`ScanMatchPose`: a scan-to-map match (``scan_matching.py``) as a direct pose measurement.

``MapLandmarks.near(layers, s_m)`` collects the landmark records of the s-layer around the current s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lastmile.core.errors import MessageError
from lastmile.core.geometry import wrap_angle_rad
from lastmile.core.stamp import Stamp
from lastmile.hdmap.layers import SLayerDatabase

CHI2_2DOF_999 = 13.815510557964274

Linearised = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(innovation (m,), H (m, 3) over x_m, y_m, yaw_rad, R (m, m))."""


class PoseMeasurement(Protocol):
    """A measurement of the planar pose, linearised by the filter at its prediction."""

    @property
    def stamp(self) -> Stamp: ...

    def linearize(self, pose: np.ndarray, covariance: np.ndarray) -> Linearised | None:
        """Innovation, Jacobian, noise at ``pose`` (3,) with ``covariance`` (3, 3); None: nothing to use."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class MapLandmarks:
    """Mapped landmarks near the vehicle: ``poles`` (n, 2) and facade ``segments`` (k, 2, 2), map frame, m."""

    poles: np.ndarray
    segments: np.ndarray

    @staticmethod
    def near(layers: SLayerDatabase, s_m: float) -> MapLandmarks:
        """The s-layer's landmark records at ``s_m`` (within ``LANDMARK_RADIUS_M``)."""
        poles: list[np.ndarray] = []
        segments: list[np.ndarray] = []
        for mark in layers.landmarks_near(s_m):
            xy = np.asarray(mark.xy, dtype=float).reshape(-1, 2)
            if mark.kind == "light_pole":
                poles.append(xy[0])
            elif mark.kind == "building_facade":
                segments.extend(np.stack([xy[:-1], xy[1:]], axis=1))
        return MapLandmarks(
            poles=np.array(poles, dtype=np.float64).reshape(-1, 2),
            segments=np.array(segments, dtype=np.float64).reshape(-1, 2, 2),
        )


def _associate(d2: np.ndarray, ambiguity_ratio: float) -> int | None:
    """Index of the candidate with the smallest squared Mahalanobis distance, if gated and unambiguous."""
    if d2.size == 0:
        return None
    order = np.argsort(d2)
    best = int(order[0])
    if d2[best] > CHI2_2DOF_999:
        return None
    if d2.size > 1 and d2[order[1]] < ambiguity_ratio**2 * max(d2[best], 1.0):
        return None
    return best


@dataclass(frozen=True, slots=True, kw_only=True)
class PoleDetections:
    """Light-pole centres detected by the LiDAR.

    Attributes:
        stamp: capture time, µs.
        points_base: (k, 2) pole centres in the base frame (x forward, y left), m.
        std_m: one-sigma detection error per axis, m (every point's, unless ``point_std_m``).
        landmarks: the mapped landmarks to associate with.
        ambiguity_ratio: the second-nearest map pole must be this many times farther (Mahalanobis).
        point_std_m: (k,) one-sigma error per axis of each point (a near pole is seen better than a
            far one); None: ``std_m`` for all.
    """

    stamp: Stamp
    points_base: np.ndarray
    std_m: float
    landmarks: MapLandmarks
    ambiguity_ratio: float = 2.0
    point_std_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        pts = np.asarray(self.points_base, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or not np.isfinite(pts).all():
            raise MessageError(f"PoleDetections.points_base: expected finite (k, 2), got shape {pts.shape}")
        if not (self.std_m > 0 and math.isfinite(self.std_m)):
            raise MessageError(f"PoleDetections.std_m: expected a positive number, got {self.std_m}")
        if self.point_std_m is not None:
            std = np.asarray(self.point_std_m, dtype=float)
            if std.shape != (len(pts),) or not (np.isfinite(std).all() and (std > 0).all()):
                raise MessageError(
                    f"PoleDetections.point_std_m: expected {len(pts)} positive numbers, got shape {std.shape}"
                )

    def linearize(self, pose: np.ndarray, covariance: np.ndarray) -> Linearised | None:
        x, y, yaw = (float(v) for v in pose)
        c, s = math.cos(yaw), math.sin(yaw)
        rot = np.array([[c, -s], [s, c]])
        pts = np.asarray(self.points_base, dtype=float)
        stds = np.full(len(pts), self.std_m) if self.point_std_m is None else np.asarray(self.point_std_m)
        innovations, rows, blocks = [], [], []
        poles = self.landmarks.poles
        for p, std in zip(pts, stds, strict=True):
            r_det = float(std) ** 2 * np.eye(2)
            predicted = np.array([x, y]) + rot @ p
            # d(map point)/d(pose) = [I, dR/dyaw p]: the detection's map position moves with the pose.
            h = np.array([[1.0, 0.0, -s * p[0] - c * p[1]], [0.0, 1.0, c * p[0] - s * p[1]]])
            cov = h @ covariance @ h.T + rot @ r_det @ rot.T
            diff = poles - predicted
            d2 = np.einsum("ij,ij->i", diff @ np.linalg.inv(cov), diff) if poles.size else np.zeros(0)
            k = _associate(d2, self.ambiguity_ratio)
            if k is None:
                continue
            # Measurement: the mapped pole = pose + R p; innovation = map pole - predicted.
            innovations.append(diff[k])
            rows.append(h)
            blocks.append(rot @ r_det @ rot.T)
        if not rows:
            return None
        r = np.zeros((2 * len(blocks), 2 * len(blocks)))
        for i, b in enumerate(blocks):
            r[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = b
        return np.concatenate(innovations), np.vstack(rows), r


@dataclass(frozen=True, slots=True, kw_only=True)
class FacadeDetections:
    """Building planes detected by the LiDAR, each a line in the base frame.

    Attributes:
        stamp: capture time, µs.
        lines_base: (k, 2): distance from the base origin to the line (m, > 0) and the angle of the
            normal pointing from the base to the line (rad, base frame).
        distance_std_m, angle_std_rad: one-sigma errors of the fitted line (every line's, unless
            ``line_std``).
        landmarks: the mapped landmarks to associate with.
        ambiguity_ratio: as for poles.
        line_std: (k, 2) one-sigma distance (m) and angle (rad) errors of each line; None: the
            scalars for all.
    """

    stamp: Stamp
    lines_base: np.ndarray
    distance_std_m: float
    angle_std_rad: float
    landmarks: MapLandmarks
    ambiguity_ratio: float = 2.0
    line_std: np.ndarray | None = None

    def __post_init__(self) -> None:
        lines = np.asarray(self.lines_base, dtype=float)
        if lines.ndim != 2 or lines.shape[1] != 2 or not np.isfinite(lines).all() or (lines[:, 0] <= 0).any():
            raise MessageError(
                "FacadeDetections.lines_base: expected finite (k, 2) with positive distances, "
                f"got shape {lines.shape}"
            )
        if self.line_std is not None:
            std = np.asarray(self.line_std, dtype=float)
            if std.shape != (len(lines), 2) or not (np.isfinite(std).all() and (std > 0).all()):
                raise MessageError(
                    f"FacadeDetections.line_std: expected ({len(lines)}, 2) positive numbers, "
                    f"got shape {std.shape}"
                )

    def linearize(self, pose: np.ndarray, covariance: np.ndarray) -> Linearised | None:
        x, y, yaw = (float(v) for v in pose)
        lines = np.asarray(self.lines_base, dtype=float)
        stds = (
            np.tile([self.distance_std_m, self.angle_std_rad], (len(lines), 1))
            if self.line_std is None
            else np.asarray(self.line_std, dtype=float)
        )
        innovations, rows, blocks = [], [], []
        segs = self.landmarks.segments
        for (rho, alpha), std in zip(lines, stds, strict=True):
            r = np.diag(std**2)
            candidates = []
            for a, b in segs:
                pred = _line_in_base(a, b, x, y, yaw)
                if pred is None:
                    continue
                (rho_p, alpha_p), h = pred
                nu = np.array([rho - rho_p, wrap_angle_rad(alpha - alpha_p)])
                cov = h @ covariance @ h.T + r
                candidates.append((float(nu @ np.linalg.solve(cov, nu)), nu, h))
            k = _associate(np.array([cand[0] for cand in candidates]), self.ambiguity_ratio)
            if k is None:
                continue
            innovations.append(candidates[k][1])
            rows.append(candidates[k][2])
            blocks.append(r)
        if not rows:
            return None
        r_all = np.zeros((2 * len(blocks), 2 * len(blocks)))
        for i, b in enumerate(blocks):
            r_all[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = b
        return np.concatenate(innovations), np.vstack(rows), r_all


def _line_in_base(a: np.ndarray, b: np.ndarray, x: float, y: float, yaw: float):
    """A map segment's line seen from the pose: (distance, normal angle in base frame) and its Jacobian."""
    d = b - a
    length = float(np.hypot(*d))
    if length < 1e-6:
        return None
    n = np.array([-d[1], d[0]]) / length
    dist = float(n @ (a - np.array([x, y])))
    if dist < 0:
        n, dist = -n, -dist
    if dist < 1e-3:
        return None
    alpha = wrap_angle_rad(math.atan2(n[1], n[0]) - yaw)
    h = np.array([[-n[0], -n[1], 0.0], [0.0, 0.0, -1.0]])
    return (dist, alpha), h


@dataclass(frozen=True, slots=True, kw_only=True)
class ScanMatchPose:
    """A scan-to-map match of the base pose with its (3, 3) covariance of (x_m, y_m, yaw_rad)."""

    stamp: Stamp
    x_m: float
    y_m: float
    yaw_rad: float
    covariance: np.ndarray

    def linearize(self, pose: np.ndarray, covariance: np.ndarray) -> Linearised | None:
        cov = np.asarray(self.covariance, dtype=float)
        if cov.shape != (3, 3) or not np.isfinite(cov).all():
            return None  # a degenerate match (infinite covariance) carries no information
        nu = np.array([self.x_m - pose[0], self.y_m - pose[1], wrap_angle_rad(self.yaw_rad - pose[2])])
        return nu, np.eye(3), cov
