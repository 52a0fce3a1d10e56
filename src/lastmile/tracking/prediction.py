"""Motion prediction of tracked objects: constant velocity (Snow Lion) and a map-aware variant.

Constant velocity (Snow Lion's predictor): ``p(t) = p0 + v t``. Its one-sigma error per axis grows as

    std(t) = sqrt(pos_std^2 + (velocity_std t)^2 + (accel_std t^2 / 2)^2)

from the track's position error, an assumed velocity error and unmodelled acceleration.

Map-aware (``MapAwarePredictor``), using ``lastmile.hdmap``:

- a vehicle (car) on a drivable lanelet whose velocity agrees with the lanelet's direction follows the
  centre line (into the straightest successor at each lanelet's end) at its current speed, and brakes
  to stop at a stop line on its way (constant deceleration from where it would need ``stop_decel``).
  Along-track error grows as in constant velocity; across the lane it stays ``lane_lateral_std_m``.
- a pedestrian (or animal) moving towards a crosswalk within ``crosswalk_reach_m`` (heading within
  ``crosswalk_heading_tol_rad`` of the direction to it) walks to its nearest point, then across it to
  the far side along its long axis, at its speed (at least ``min_walk_speed_mps``).
- anything else keeps constant velocity.

Horizon and sampling: ``horizon_s`` (5 s) at ``step_s`` (0.5 s). Predictions beyond a few seconds are
indicative only: errors grow quadratically with time, and interactions between objects are ignored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.boxes3d import TrackedBoxes
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import point_in_polygon
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.predictions import PREDICTION_MODES, PredictedPaths
from lastmile.core.stamp import Stamp
from lastmile.hdmap.model import DRIVABLE_SUBTYPES, HDMap

_CV, _LANE, _CROSS = (PREDICTION_MODES.index(m) for m in PREDICTION_MODES)


@dataclass(frozen=True, slots=True, kw_only=True)
class PredictionConfig:
    """Prediction parameters.

    Attributes:
        horizon_s: how far ahead to predict.
        step_s: sampling step.
        velocity_std_mps: assumed error of a track's velocity.
        accel_std_mps2: unmodelled acceleration.
        lane_lateral_std_m: across-lane error of a lane-following vehicle.
        lane_heading_tol_rad: largest angle between velocity and lane direction to follow the lane.
        min_lane_speed_mps: slower vehicles keep constant velocity (their heading is unreliable).
        stop_decel_mps2: deceleration of a vehicle stopping at a stop line.
        crosswalk_reach_m: a pedestrian farther than this from a crosswalk is not heading to it.
        crosswalk_heading_tol_rad: largest angle between velocity and direction to the crosswalk.
        min_walk_speed_mps: a pedestrian heading to a crosswalk walks at least this fast.
    """

    horizon_s: float = 5.0
    step_s: float = 0.5
    velocity_std_mps: float = 0.5
    accel_std_mps2: float = 1.0
    lane_lateral_std_m: float = 0.5
    lane_heading_tol_rad: float = 0.6
    min_lane_speed_mps: float = 1.0
    stop_decel_mps2: float = 2.0
    crosswalk_reach_m: float = 10.0
    crosswalk_heading_tol_rad: float = 0.6
    min_walk_speed_mps: float = 0.8

    def __post_init__(self) -> None:
        if not (0.0 < self.step_s <= self.horizon_s):
            raise ConfigError(
                f"PredictionConfig: expected 0 < step_s <= horizon_s, got {self.step_s}, {self.horizon_s}"
            )
        for name in ("velocity_std_mps", "accel_std_mps2", "lane_lateral_std_m", "crosswalk_reach_m"):
            if getattr(self, name) < 0.0:
                raise ConfigError(f"PredictionConfig.{name}: expected >= 0, got {getattr(self, name)}")
        if self.stop_decel_mps2 <= 0.0:
            raise ConfigError(f"PredictionConfig.stop_decel_mps2: expected > 0, got {self.stop_decel_mps2}")

    def times(self) -> np.ndarray:
        n = math.floor(self.horizon_s / self.step_s + 1e-9)
        return self.step_s * np.arange(1, n + 1)


def _cv_std(pos_std: np.ndarray, t: np.ndarray, cfg: PredictionConfig) -> np.ndarray:
    return np.sqrt(
        pos_std[:, None] ** 2 + (cfg.velocity_std_mps * t) ** 2 + (0.5 * cfg.accel_std_mps2 * t**2) ** 2
    )


def predict_constant_velocity(tracks: TrackedBoxes, config: PredictionConfig | None = None) -> PredictedPaths:
    """Constant-velocity paths for every track."""
    t = tracks.table
    return _cv_paths(tracks.stamp, tracks.ids, t[:, 0:2], t[:, 7:9], t[:, 10], config or PredictionConfig())


def _cv_paths(
    stamp: Stamp,
    ids: np.ndarray,
    xy_m: np.ndarray,
    v_mps: np.ndarray,
    pos_std_m: np.ndarray,
    cfg: PredictionConfig,
) -> PredictedPaths:
    t = cfg.times()
    return PredictedPaths(
        stamp=stamp,
        ids=ids,
        times_s=t,
        xy_m=xy_m[:, None, :] + v_mps[:, None, :] * t[None, :, None],
        std_m=_cv_std(pos_std_m, t, cfg),
        mode=np.full(len(ids), _CV),
    )


def _angle_diff(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2.0 * math.pi) - math.pi)


class MapAwarePredictor:
    """Vehicles follow lanes and stop at stop lines, pedestrians seek crosswalks; else constant velocity."""

    def __init__(self, hdmap: HDMap, config: PredictionConfig | None = None) -> None:
        self.hdmap = hdmap
        self.config = config or PredictionConfig()
        self._stop_at_end = {sl.lanelet_id: sl for sl in hdmap.stop_lines}

    def predict(self, tracks: TrackedBoxes) -> PredictedPaths:
        """One path per track (see the module docstring for the rules)."""
        t = tracks.table
        return self._predict(tracks.stamp, tracks.ids, t[:, 0:2], t[:, 7:9], tracks.class_id, t[:, 10])

    def predict_objects(self, tracks: TrackedObjects) -> PredictedPaths:
        """The same for the stack's published tracks (:class:`TrackedObjects`, columns by name)."""
        t = tracks.table
        col = TRACK_COLUMNS.index
        return self._predict(
            tracks.stamp,
            tracks.ids,
            t[:, [col("x_m"), col("y_m")]],
            t[:, [col("vx_mps"), col("vy_mps")]],
            t[:, col("class_id")].astype(np.int64),
            t[:, col("pos_std_m")],
        )

    def _predict(
        self,
        stamp: Stamp,
        ids: np.ndarray,
        xy_m: np.ndarray,
        v_mps: np.ndarray,
        class_id: np.ndarray,
        pos_std_m: np.ndarray,
    ) -> PredictedPaths:
        cfg = self.config
        base = _cv_paths(stamp, ids, xy_m, v_mps, pos_std_m, cfg)
        t = base.times_s
        xy = base.xy_m.copy()
        std = base.std_m.copy()
        mode = base.mode.copy()
        for i in range(len(ids)):
            x, y = float(xy_m[i, 0]), float(xy_m[i, 1])
            vx, vy = float(v_mps[i, 0]), float(v_mps[i, 1])
            cls = int(class_id[i])
            path = None
            if cls == ObjectClass.CAR:
                path = self._lane_path(x, y, vx, vy, t)
                if path is not None:
                    # Per-axis figure: mean of the along-track (CV growth) and across-lane variances.
                    std[i] = np.sqrt(0.5 * (std[i] ** 2 + cfg.lane_lateral_std_m**2))
                    mode[i] = _LANE
            elif cls in (ObjectClass.PEDESTRIAN, ObjectClass.ANIMAL):
                path = self._crosswalk_path(x, y, vx, vy, t)
                if path is not None:
                    mode[i] = _CROSS
            if path is not None:
                xy[i] = path
        return PredictedPaths(stamp=stamp, ids=ids, times_s=t, xy_m=xy, std_m=std, mode=mode)

    def _lane_path(self, x: float, y: float, vx: float, vy: float, t: np.ndarray) -> np.ndarray | None:
        cfg = self.config
        speed = math.hypot(vx, vy)
        if speed < cfg.min_lane_speed_mps:
            return None
        lid = self.hdmap.lanelet_at(x, y)
        if lid is None or self.hdmap.lanelets[lid].subtype not in DRIVABLE_SUBTYPES:
            return None
        line = self.hdmap.lanelets[lid].centerline
        s0 = line.project(x, y).s_m
        if _angle_diff(line.heading_at(s0), math.atan2(vy, vx)) > cfg.lane_heading_tol_rad:
            return None
        # Chain centre lines ahead far enough for the horizon; note the first stop line on the way.
        need = speed * float(t[-1]) + 1.0
        pieces = [line.sub(s0, line.length_m, step_m=0.5)]
        ahead = line.length_m - s0
        stop_at: float | None = ahead if lid in self._stop_at_end else None
        cur = lid
        while ahead < need and stop_at is None:
            nxt = self._straightest_successor(cur)
            if nxt is None:
                break
            nl = self.hdmap.lanelets[nxt].centerline
            pieces.append(nl.sub(0.0, nl.length_m, step_m=0.5))
            ahead += nl.length_m
            cur = nxt
            if cur in self._stop_at_end:
                stop_at = ahead
        pts = np.vstack(pieces)
        seg = np.hypot(*np.diff(pts, axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        dist = speed * t
        if stop_at is not None:
            # Brake at stop_decel from the point where that stops the vehicle at the line.
            brake_start = max(stop_at - speed**2 / (2.0 * cfg.stop_decel_mps2), 0.0)
            decel = speed**2 / (2.0 * max(stop_at - brake_start, 1e-3))
            t_brake = brake_start / speed
            tb = np.clip(t - t_brake, 0.0, speed / decel)
            dist = np.where(t <= t_brake, dist, brake_start + speed * tb - 0.5 * decel * tb**2)
        dist = np.minimum(dist, s[-1])
        return np.column_stack([np.interp(dist, s, pts[:, 0]), np.interp(dist, s, pts[:, 1])])

    def _straightest_successor(self, lid: int) -> int | None:
        succ = self.hdmap.successors(lid)
        if not succ:
            return None
        end = self.hdmap.lanelets[lid].centerline
        h = end.heading_at(end.length_m)
        return min(succ, key=lambda k: _angle_diff(self.hdmap.lanelets[k].centerline.heading_at(0.0), h))

    def _crosswalk_path(self, x: float, y: float, vx: float, vy: float, t: np.ndarray) -> np.ndarray | None:
        cfg = self.config
        speed = math.hypot(vx, vy)
        if speed < 0.2 or not self.hdmap.crosswalks:
            return None
        heading = math.atan2(vy, vx)
        best = None
        for cw in self.hdmap.crosswalks:
            poly = np.asarray(cw.polygon, dtype=float)
            near = _nearest_on_polygon(poly, x, y)
            d = math.hypot(near[0] - x, near[1] - y)
            inside = d < 1e-6
            if d > cfg.crosswalk_reach_m:
                continue
            centre = poly.mean(axis=0)
            aim = math.atan2(centre[1] - y, centre[0] - x)
            if not inside and _angle_diff(aim, heading) > cfg.crosswalk_heading_tol_rad:
                continue
            if best is None or d < best[0]:
                best = (d, near, poly, centre)
        if best is None:
            return None
        _, near, poly, centre = best
        # Long axis of the crosswalk (it spans the road); cross to the side away from the pedestrian.
        evals, evecs = np.linalg.eigh(np.cov((poly - centre).T))
        axis = evecs[:, int(np.argmax(evals))]
        half = 0.5 * float(np.ptp((poly - centre) @ axis))
        if float((centre - np.array([x, y])) @ axis) < 0.0:
            axis = -axis
        far = centre + axis * (half + 0.5)
        pts = np.array([[x, y], near, far])
        seg = np.hypot(*np.diff(pts, axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        dist = np.minimum(max(speed, cfg.min_walk_speed_mps) * t, s[-1])
        return np.column_stack([np.interp(dist, s, pts[:, 0]), np.interp(dist, s, pts[:, 1])])


def _nearest_on_polygon(poly: np.ndarray, x: float, y: float) -> np.ndarray:
    """Nearest point of a polygon (the point itself when inside)."""
    if point_in_polygon(x, y, poly):
        return np.array([x, y])
    a = poly
    b = np.roll(poly, -1, axis=0)
    ab = b - a
    u = np.clip(((np.array([x, y]) - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-12), 0.0, 1.0)
    cand = a + u[:, None] * ab
    return cand[int(np.argmin(np.hypot(cand[:, 0] - x, cand[:, 1] - y)))]
