"""GEM's waypoint follower (its section IV): recorded waypoints, the next one targeted within 2 m.

The follower aims at waypoints in sequence, switching to the next once the vehicle is within 2 m of the
current one, and commands a yaw rate omega_c = K_p theta_error toward it; the yaw rate becomes a wheel
angle through the bicycle model (section II-B). Waypoint files hold (latitude, longitude, speed) triplets
recorded every 1 m; the speed of each waypoint is capped by v_max = sqrt(0.5 r), r the path radius there
(lateral acceleration at most 0.5 m/s^2).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.control.command_filters import SteeringOutput
from lastmile.control.path_errors import PathTracker, PlannedPointLaw, check_speed
from lastmile.control.speed_reference import SteersFromPathAlone
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry

#: GEM's lateral acceleration limit for the recorded speeds (m/s^2).
GEM_MAX_LATERAL_ACCEL_MPS2 = 0.5


@dataclass(frozen=True, slots=True, kw_only=True)
class WaypointFollowerConfig:
    """GEM's follower.

    Attributes:
        spacing_m: waypoint spacing along the path (GEM records every 1 m).
        switch_radius_m: the next waypoint is targeted once the current one is this close (GEM: 2 m).
        yaw_rate_gain_per_s: K_p of omega_c = K_p theta_error. GEM does not publish it; the default is
            2 v / d at GEM's figure-8 speed (3 m/s) and its 2 m switch radius, the gain at which the law
            matches pure pursuit to the same point for small errors.
        steer_lowpass_tau_s: time constant of the steering command's low-pass filter.
        gain_reference_speed_mps: below this speed the yaw-rate gain is scaled by v / this speed. GEM's
            constant K_p asks for a wheel angle atan(K_p theta L / v) that grows without bound as the
            shuttle slows (pulling into a bay, it saturated and oscillated off the road in our closed
            loop); scaled, the wheel angle for a given bearing error stays what it is at GEM's 3 m/s.
            None is GEM's law as published (constant K_p at every speed).
    """

    spacing_m: float = 1.0
    switch_radius_m: float = 2.0
    yaw_rate_gain_per_s: float = 3.0
    steer_lowpass_tau_s: float = 0.0
    gain_reference_speed_mps: float | None = 3.0

    def __post_init__(self) -> None:
        if not (0.0 < self.spacing_m < self.switch_radius_m):
            raise ConfigError(
                f"WaypointFollowerConfig: expected 0 < spacing_m < switch_radius_m, "
                f"got {self.spacing_m} and {self.switch_radius_m}"
            )
        if not self.yaw_rate_gain_per_s > 0.0:
            raise ConfigError(
                f"WaypointFollowerConfig.yaw_rate_gain_per_s: expected > 0, got {self.yaw_rate_gain_per_s}"
            )


def curvature_capped_speeds_mps(
    xy_m: np.ndarray, speeds_mps: np.ndarray, max_lateral_accel_mps2: float = GEM_MAX_LATERAL_ACCEL_MPS2
) -> np.ndarray:
    """Speeds (M,) capped by v_max = sqrt(a_lat r) at each waypoint of ``xy_m`` (M, 2).

    GEM estimates r = v / omega from the recorded speed and yaw rate; a file holds positions only, so
    r here is the radius of the circle through each waypoint and its two neighbours.
    """
    xy = np.asarray(xy_m, dtype=np.float64)
    v = np.asarray(speeds_mps, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or v.shape != (len(xy),):
        raise MessageError(
            f"curvature_capped_speeds_mps: expected (M, 2) points and (M,) speeds, "
            f"got {xy.shape} and {v.shape}"
        )
    if len(xy) < 3:
        return v.copy()
    # Circumcircle of each waypoint and its two neighbours (the ends take their neighbour's).
    p0, p1, p2 = xy[:-2], xy[1:-1], xy[2:]
    u, w = p1 - p0, p2 - p0
    cross = u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]
    d = p2 - p1
    denom = np.hypot(u[:, 0], u[:, 1]) * np.hypot(d[:, 0], d[:, 1]) * np.hypot(w[:, 0], w[:, 1])
    inner = np.where(denom > 1e-12, 2.0 * np.abs(cross) / np.maximum(denom, 1e-12), 0.0)
    kappa = np.concatenate([inner[:1], inner, inner[-1:]])
    cap = np.sqrt(max_lateral_accel_mps2 / np.maximum(kappa, 1e-9))
    return np.minimum(v, cap)


@dataclass(frozen=True, slots=True, kw_only=True)
class WaypointFile:
    """A recorded waypoint list in the map frame.

    Attributes:
        xy_m: (M, 2) float64 waypoint positions (map frame).
        speed_mps: (M,) float64 speeds, already capped by v_max = sqrt(0.5 r).
    """

    xy_m: np.ndarray
    speed_mps: np.ndarray

    def path(self) -> Polyline:
        """The waypoints as a path for the follower (``GemWaypointFollower.step``)."""
        return Polyline(self.xy_m)

    def speed_at_mps(self, s_m: float) -> float:
        """The recorded (capped) speed of the last waypoint at or before station ``s_m`` of ``path()``:
        GEM passes the target waypoint's speed to the twist controller."""
        # Stations of the waypoints themselves (the path drops repeated points; the file keeps them).
        step = np.hypot(*np.diff(self.xy_m, axis=0).T)
        stations = np.concatenate([[0.0], np.cumsum(step)])
        i = int(np.clip(np.searchsorted(stations, s_m, side="right") - 1, 0, len(stations) - 1))
        return float(self.speed_mps[i])


def read_waypoint_file(
    path: str | Path, map_from_latlon: Callable[[float, float], tuple[float, float]]
) -> WaypointFile:
    """Read a GEM waypoint file: one ``latitude, longitude, speed`` triplet a line (degrees, m/s).

    ``map_from_latlon`` projects a (lat, lon) pair into the map frame (the map's own projector, e.g.
    Lanelet2's UtmProjector with the map origin). Blank lines and lines starting with ``#`` are skipped.

    Raises:
        MessageError: a line without three numbers, an out-of-range coordinate or a negative speed,
            naming the file and line; fewer than two waypoints.
    """
    rows: list[tuple[float, float, float]] = []
    with Path(path).open(newline="") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            if len(row) != 3:
                raise MessageError(
                    f"{path}, line {lineno}: expected 'latitude, longitude, speed', got {len(row)} fields"
                )
            try:
                lat, lon, speed = (float(f) for f in row)
            except ValueError:
                raise MessageError(f"{path}, line {lineno}: expected three numbers, got {row!r}") from None
            if not (abs(lat) <= 90.0 and abs(lon) <= 180.0):
                raise MessageError(
                    f"{path}, line {lineno}: expected latitude in [-90, 90] and longitude in [-180, 180], "
                    f"got {lat}, {lon}"
                )
            if not (math.isfinite(speed) and speed >= 0.0):
                raise MessageError(
                    f"{path}, line {lineno}, column speed: expected a speed >= 0 m/s, got {speed}"
                )
            rows.append((lat, lon, speed))
    if len(rows) < 2:
        raise MessageError(f"{path}: expected at least two waypoints, got {len(rows)}")
    xy = np.array([map_from_latlon(lat, lon) for lat, lon, _ in rows], dtype=np.float64)
    speeds = curvature_capped_speeds_mps(xy, np.array([r[2] for r in rows]))
    return WaypointFile(xy_m=xy, speed_mps=speeds)


class GemWaypointFollower(SteersFromPathAlone, PlannedPointLaw):
    """GEM: omega_c = K_p theta_error toward the current waypoint, delta from the bicycle model.

    Controllers receive a new path each planning cycle: its waypoints are the path sampled every
    ``spacing_m``; the target carries over as the point on the new path nearest the old target.
    """

    def __init__(self, geometry: VehicleGeometry, config: WaypointFollowerConfig | None = None) -> None:
        self.geometry = geometry
        self.config = config or WaypointFollowerConfig()
        self._output = SteeringOutput(
            geometry.max_steer_rad, geometry.max_steer_rate_radps, self.config.steer_lowpass_tau_s
        )
        self._path: Polyline | None = None
        self._target_s_m = 0.0
        self._tracker = PathTracker()

    def _target(self, path: Polyline, ref: SE2) -> tuple[float, float]:
        c = self.config
        here = self._tracker.errors(path, ref).s_m
        if self._path is not path:
            if self._path is None:
                target_s = here
            else:
                tx, ty, _ = self._path.point_at(self._target_s_m)
                target_s = path.project(tx, ty, hint_s_m=here, window_m=c.switch_radius_m + 5.0).s_m
            self._path = path
        else:
            target_s = self._target_s_m
        # Waypoints lie at multiples of the spacing; never aim behind the vehicle (a missed waypoint
        # would otherwise be chased in a loop).
        target_s = max(target_s, math.ceil(here / c.spacing_m) * c.spacing_m)
        end = path.length_m if not path.closed else math.inf
        while True:
            x, y, _ = path.point_at(target_s)
            if math.hypot(x - ref.x_m, y - ref.y_m) >= c.switch_radius_m or target_s >= end:
                break
            target_s += c.spacing_m
        self._target_s_m = target_s
        return x, y

    def speed_cap_mps(self, path: Polyline, path_s_m: float, cap_mps: float, decel_mps2: float) -> float:
        """GEM's speed law on the live path: the waypoints ahead (every ``spacing_m``) capped by
        v_max = sqrt(0.5 r), and the lowest of them that braking at ``decel_mps2`` still reaches.

        GEM caps the speeds of its recorded file once; the stack's path is planned anew each cycle, so
        the same cap is applied to it here. Without it the follower entered a bay at the 1 m/s^2 curve
        speed of the default law (3.5 m/s, 0.08 /m) and its 2 m aim point swung the body off the road.
        """
        c = self.config
        reach = cap_mps**2 / (2.0 * decel_mps2) + c.switch_radius_m
        end = path_s_m + reach if path.closed else min(path.length_m, path_s_m + reach)
        s = np.arange(path_s_m, end + 1e-9, c.spacing_m)
        if len(s) < 3:
            return cap_mps
        capped = curvature_capped_speeds_mps(path.points_at(s), np.full(len(s), cap_mps))
        reachable = np.sqrt(capped**2 + 2.0 * decel_mps2 * (s - path_s_m))
        return float(min(cap_mps, reachable.min()))

    def step(
        self, dt_s: float, map_from_base: SE2, speed_mps: float, path: Polyline, rear_steer: bool = True
    ) -> tuple[float, float]:
        """``rear_steer=False`` keeps the rear wheels straight (at a curb, so the tail cannot swing in)."""
        check_speed("GemWaypointFollower.step", speed_mps)
        g, c = self.geometry, self.config
        all_wheel = g.all_wheel_steer and rear_steer
        ref = map_from_base.compose(SE2(g.wheelbase_m / 2.0, 0.0, 0.0)) if all_wheel else map_from_base
        tx, ty = self._target(path, ref)
        theta_error = wrap_angle_rad(math.atan2(ty - ref.y_m, tx - ref.x_m) - ref.yaw_rad)
        v = max(speed_mps, 0.5)  # the bicycle inversion is singular at rest
        gain = c.yaw_rate_gain_per_s
        if c.gain_reference_speed_mps is not None and v < c.gain_reference_speed_mps:
            gain *= v / c.gain_reference_speed_mps
        omega = gain * theta_error
        base = g.wheelbase_m / 2.0 if all_wheel else g.wheelbase_m
        delta = self._output.step(dt_s, math.atan(omega * base / v))
        return delta, (-delta if all_wheel else 0.0)
