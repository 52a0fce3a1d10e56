"""Errors of a vehicle reference point against a path: cross-track, heading, station and curvature."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import MessageError
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry

# Half-width (m) of the chord the path heading is measured over: a polyline's segment heading jumps at
# every vertex, a chord across the vertex turns smoothly.
_HEADING_CHORD_M = 0.5
# Window (m) of the three-point curvature estimate (as Polyline.curvature_at).
CURVATURE_WINDOW_M = 2.0


@dataclass(frozen=True, slots=True, kw_only=True)
class PathErrors:
    """Where a reference point is relative to a path.

    Attributes:
        s_m: station of the nearest path point.
        lateral_m: signed distance to the path, positive when the point is left of it.
        heading_error_rad: vehicle yaw minus path heading, wrapped to [-pi, pi) (positive: pointing
            left of the path).
        path_heading_rad: heading of the path at ``s_m``.
        curvature_1pm: signed path curvature at ``s_m`` (left turn positive).
    """

    s_m: float
    lateral_m: float
    heading_error_rad: float
    path_heading_rad: float
    curvature_1pm: float


def check_speed(where: str, speed_mps: float) -> None:
    """Raise MessageError naming ``where`` when the speed is not finite (SE2 checks its own fields)."""
    if not math.isfinite(speed_mps):
        raise MessageError(f"{where}: expected a finite speed in m/s, got {speed_mps}")


def path_heading_rad(path: Polyline, s_m: float) -> float:
    """Heading of the chord across ``s_m`` (smooth across vertices, unlike the segment heading)."""
    ax, ay, _ = path.point_at(s_m - _HEADING_CHORD_M)
    bx, by, _ = path.point_at(s_m + _HEADING_CHORD_M)
    if ax == bx and ay == by:
        return path.heading_at(s_m)
    return math.atan2(by - ay, bx - ax)


def curvature_profile(path: Polyline, s_m: np.ndarray, window_m: float = CURVATURE_WINDOW_M) -> np.ndarray:
    """Signed curvature (1/m) at each station of ``s_m`` (M,): the circle through s - w, s, s + w."""
    s = np.asarray(s_m, dtype=np.float64)
    a = path.points_at(s - window_m)
    b = path.points_at(s)
    c = path.points_at(s + window_m)
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    ab, bc, ac = b - a, c - b, c - a
    denom = np.hypot(ab[:, 0], ab[:, 1]) * np.hypot(bc[:, 0], bc[:, 1]) * np.hypot(ac[:, 0], ac[:, 1])
    out = np.zeros_like(s)
    ok = denom > 1e-12
    out[ok] = 2.0 * cross[ok] / denom[ok]
    return out


def path_errors(path: Polyline, point: SE2, hint_s_m: float | None = None) -> PathErrors:
    """Errors of ``point`` (position and yaw) against ``path``; ``hint_s_m`` keeps the search local."""
    f = path.project(point.x_m, point.y_m, hint_s_m=hint_s_m, window_m=10.0)
    heading = path_heading_rad(path, f.s_m)
    return PathErrors(
        s_m=f.s_m,
        lateral_m=f.d_m,
        heading_error_rad=wrap_angle_rad(point.yaw_rad - heading),
        path_heading_rad=heading,
        curvature_1pm=path.curvature_at(f.s_m, CURVATURE_WINDOW_M),
    )


def point_ahead(map_from_base: SE2, distance_m: float) -> SE2:
    """The pose ``distance_m`` ahead of the rear axle along the body axis (same yaw)."""
    return map_from_base.compose(SE2(distance_m, 0.0, 0.0))


def path_ahead_of(path: Polyline, ahead_m: float) -> Polyline:
    """The path traced by the body point ``ahead_m`` ahead of the point that traces ``path``.

    A body point whose velocity lies along the body axis (the rear axle with front steer, the centre of
    the wheelbase with all-wheel steer) keeps the body's heading on the path's tangent; a point l ahead
    of it then traces p(s) + l t(s). Its derivative, t + l kappa n, never vanishes, so the shifted line
    has no cusp however tight the curve.
    """
    s = path.s_m
    a = path.points_at(s - _HEADING_CHORD_M)
    b = path.points_at(s + _HEADING_CHORD_M)
    heading = np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])
    xy = path.xy_m + ahead_m * np.c_[np.cos(heading), np.sin(heading)]
    return Polyline(xy[:-1] if path.closed else xy, closed=path.closed)


class PlannedPointLaw:
    """Mixin of the lateral laws whose own point is the one the planner lays its path for.

    The local planner lays the path of the rear axle (of the centre of the wheelbase with all-wheel
    steer, where the body's velocity lies along its axis). A law measured at another point (Stanley's
    front axle, the MPC's centre of gravity) overrides :meth:`path_lead_m`, and the stack feeds it the
    path that point must trace (:func:`path_ahead_of`).
    """

    def path_lead_m(self, rear_steer: bool = True) -> float:
        """How far ahead of the planned point the law's own point sits (m): none here."""
        del rear_steer
        return 0.0


def steer_for_curvature_rad(curvature_1pm: float, geometry: VehicleGeometry, all_wheel: bool) -> float:
    """Kinematic front wheel angle for a path curvature (rear = -front with all-wheel steer)."""
    if all_wheel:
        return math.atan(curvature_1pm * geometry.wheelbase_m / 2.0)
    return math.atan(curvature_1pm * geometry.wheelbase_m)


class PathTracker:
    """Remembers the station on the last path so crossings (figure-8s, loops) keep the right branch.

    Controllers are handed a new ``Polyline`` each planning cycle; on the same object the projection
    is searched near the last station, on a new one it is searched over the whole line.
    """

    def __init__(self) -> None:
        # The path itself, not its id: a freed object's id can be reused by the next path.
        self._path: Polyline | None = None
        self._s_m: float | None = None

    def errors(self, path: Polyline, point: SE2) -> PathErrors:
        hint = self._s_m if self._path is path else None
        e = path_errors(path, point, hint)
        self._path, self._s_m = path, e.s_m
        return e
