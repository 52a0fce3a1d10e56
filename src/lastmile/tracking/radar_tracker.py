"""Radar object tracker: gated Hungarian association, constant-velocity Kalman filters, M-of-N lifecycle.

Radar object lists carry position and over-ground velocity, so each track's filter measures all four
of its states. Several radars (front, rear) feed one tracker in the map frame. Tracks live in one
struct-of-arrays table so that a frame costs a few dozen NumPy calls whatever the number of tracks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects, empty_tracks
from lastmile.core.sensor_frames import RADAR_COLUMNS, RadarFrame
from lastmile.core.stamp import US_PER_S, Stamp
from lastmile.tracking import cv_kalman
from lastmile.tracking.radar_class import RadarClassConfig, classify_radar_tracks

# Footprints by class (length_m, width_m): radar object lists carry no extent.
_FOOTPRINT_M = {
    ObjectClass.UNKNOWN: (1.0, 1.0),
    ObjectClass.CAR: (4.5, 1.8),
    ObjectClass.PEDESTRIAN: (0.6, 0.6),
    ObjectClass.CYCLIST: (1.8, 0.6),
    ObjectClass.ANIMAL: (0.8, 0.4),
}
_LENGTH_BY_CLASS = np.array([_FOOTPRINT_M[ObjectClass(i)][0] for i in range(len(ObjectClass))])
_WIDTH_BY_CLASS = np.array([_FOOTPRINT_M[ObjectClass(i)][1] for i in range(len(ObjectClass))])

# Columns of the internal track table (float64; stamps in microseconds are exact below 2**53).
_X, _Y, _VX, _VY = 0, 1, 2, 3
_PP, _PV, _VV = 4, 5, 6
_T_US, _BORN_US, _SEEN_US = 7, 8, 9
_HITS, _CHANCES, _CONFIRMED, _SENSORS = 10, 11, 12, 13
_YAW, _RCS_SUM, _MAX_SPEED, _ID = 14, 15, 16, 17
_NCOL = 18
_STATE = slice(_X, _VY + 1)
_COV = slice(_PP, _VV + 1)

_MAX_SENSORS = 52  # sensor bits live in a float64 column: exact below 2**53

_OUT_X, _OUT_VY = TRACK_COLUMNS.index("x_m"), TRACK_COLUMNS.index("vy_mps")
_OUT_LENGTH, _OUT_WIDTH = TRACK_COLUMNS.index("length_m"), TRACK_COLUMNS.index("width_m")
_OUT_YAW, _OUT_CLASS = TRACK_COLUMNS.index("yaw_rad"), TRACK_COLUMNS.index("class_id")
_OUT_STD, _OUT_AGE = TRACK_COLUMNS.index("pos_std_m"), TRACK_COLUMNS.index("age_s")

_INFEASIBLE = 1e9


@dataclass(frozen=True, slots=True, kw_only=True)
class RadarTrackerConfig:
    """Tracker parameters.

    Attributes:
        gate_m: largest position distance at which a detection may update a track, m (a hard cap:
            an uncertain track must not swallow everything near it).
        gate_chi2: bound on the 4-dof squared Mahalanobis distance of position and velocity;
            18.5 is the 0.999 quantile.
        accel_noise_mps2: white-acceleration process noise of the constant-velocity model, m/s^2 per
            sqrt(Hz) (pedestrians and cars turning or braking gently).
        pos_noise_m: radar position noise (one sigma) at zero range, m.
        pos_noise_per_m: growth of position noise with range (azimuth error), m per m.
        vel_noise_mps: radar over-ground velocity noise (one sigma), m/s.
        confirm_hits: M of M-of-N: a tentative track is confirmed after this many detections ...
        confirm_window: ... within its first N chances (frames from radars that have seen it).
        t_expire_s: a track without detections for this long is deleted, s.
        max_tracks: hard bound on live tracks; births beyond it are dropped (clutter storms must not
            grow memory or time without limit).
        min_speed_for_yaw_mps: below this speed the yaw is held, not taken from the velocity, m/s.
        sensor_half_fov_rad: the radars' half field of view (the simulator's radars: 75 deg).
        blind_zone_range_m, blind_zone_hold_s: a confirmed track whose prediction lies within this
            range of a radar but outside every radar's field of view (beside the bumpers) is kept
            for up to this long without detections. Its absence from the lists there is no evidence
            that it has gone, and forgetting a goose standing beside the front corner would let the
            shuttle drive off into it.
        classes: the RCS and speed model behind ``class_id``.
    """

    gate_m: float = 3.0
    gate_chi2: float = 18.5
    accel_noise_mps2: float = 1.5
    pos_noise_m: float = 0.15
    pos_noise_per_m: float = 0.005
    vel_noise_mps: float = 0.2
    confirm_hits: int = 3
    confirm_window: int = 5
    t_expire_s: float = 0.6
    max_tracks: int = 200
    min_speed_for_yaw_mps: float = 0.5
    sensor_half_fov_rad: float = math.radians(75.0)
    blind_zone_range_m: float = 4.0
    blind_zone_hold_s: float = 8.0
    classes: RadarClassConfig = field(default_factory=RadarClassConfig)

    def __post_init__(self) -> None:
        for name in (
            "gate_m",
            "gate_chi2",
            "accel_noise_mps2",
            "pos_noise_m",
            "vel_noise_mps",
            "t_expire_s",
            "sensor_half_fov_rad",
            "blind_zone_range_m",
            "blind_zone_hold_s",
        ):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"RadarTrackerConfig.{name}: expected a positive number, got {value}")
        if not self.pos_noise_per_m >= 0:
            raise ConfigError(
                "RadarTrackerConfig.pos_noise_per_m: expected a non-negative number, "
                f"got {self.pos_noise_per_m}"
            )
        if not 1 <= self.confirm_hits <= self.confirm_window:
            raise ConfigError(
                "RadarTrackerConfig: expected 1 <= confirm_hits <= confirm_window, "
                f"got {self.confirm_hits} and {self.confirm_window}"
            )
        if self.max_tracks < 1:
            raise ConfigError(f"RadarTrackerConfig.max_tracks: expected at least 1, got {self.max_tracks}")


class RadarObjectTracker:
    """Multi-object tracker in the map frame fed by radar object lists.

    Lifecycle: every unmatched detection births a tentative track; a tentative track is confirmed
    after ``confirm_hits`` detections within ``confirm_window`` chances and deleted as soon as it can
    no longer make it; any track unseen for ``t_expire_s`` is deleted. Only confirmed tracks are
    reported. A chance is a frame from a radar that has already detected the track, so the rear radar
    does not count against an object only the front radar can see.
    """

    def __init__(self, config: RadarTrackerConfig | None = None) -> None:
        self.config = config or RadarTrackerConfig()
        self._table = np.zeros((0, _NCOL))
        self._next_id = 1
        self._sensor_bits: dict[str, int] = {}
        self._latest_us = 0
        # Where the radars were at the newest frame: the blind zone between their fields of view.
        self._map_from_base: SE2 | None = None
        self._mounts: dict[str, SE2] = {}
        self._accel_var = self.config.accel_noise_mps2**2
        self._vel_var = self.config.vel_noise_mps**2

    def __len__(self) -> int:
        """Live tracks, tentative ones included."""
        return int(self._table.shape[0])

    def update(self, frame: RadarFrame, map_from_base: SE2, base_from_sensor: SE2) -> None:
        """Fuse one radar frame.

        Args:
            frame: the radar's object list at its capture stamp (positions and over-ground
                velocities in the radar frame).
            map_from_base: the vehicle pose at ``frame.stamp``.
            base_from_sensor: the radar's mounting on the vehicle.

        Raises:
            MessageError: a negative stamp, or objects that are not a finite (N, 6) array.
        """
        objects = frame.objects
        if frame.stamp < 0:
            raise MessageError(f"RadarFrame.stamp: expected a non-negative stamp, got {frame.stamp}")
        if objects.ndim != 2 or objects.shape[1] != len(RADAR_COLUMNS) or not np.isfinite(objects).all():
            raise MessageError(
                f"RadarFrame.objects: expected a finite (N, {len(RADAR_COLUMNS)}) array, "
                f"got shape {objects.shape} with non-finite values or wrong columns"
            )
        t_us = int(frame.stamp)
        if t_us >= self._latest_us:
            self._map_from_base = map_from_base
        self._latest_us = max(self._latest_us, t_us)
        self._mounts[frame.sensor_id] = base_from_sensor
        bit = self._sensor_bit(frame.sensor_id)
        z, pos_var = self._to_map(objects, map_from_base.compose(base_from_sensor))
        table = self._table
        n_tracks = table.shape[0]
        matched_tracks = np.zeros(0, dtype=np.intp)
        matched_dets = np.zeros(0, dtype=np.intp)
        if n_tracks and len(z):
            # Tracks are predicted to the frame stamp, backwards for those already past it (a frame
            # from a slower radar). TODO(#4): rollback
            dt_s = (t_us - table[:, _T_US]) / US_PER_S
            pred_state, pred_cov = cv_kalman.predict(table[:, _STATE], table[:, _COV], dt_s, self._accel_var)
            matched_tracks, matched_dets = self._associate(pred_state, pred_cov, z, pos_var)
            if len(matched_tracks):
                self._correct(matched_tracks, matched_dets, pred_state, pred_cov, z, pos_var, objects, t_us)
        self._count_chances(matched_tracks, bit)
        self._birth(z, pos_var, objects, matched_dets, t_us, bit)
        self._prune()

    def tracks(self, stamp: Stamp) -> TrackedObjects:
        """Confirmed tracks predicted to ``stamp``, in the map frame, with every TRACK_COLUMNS filled.

        Tracks unseen for longer than ``t_expire_s`` at ``stamp`` are left out (they are deleted at
        the next frame), unless held in the blind zone beside the bumpers (``blind_zone_hold_s``).
        """
        table = self._table
        if table.shape[0]:
            table = table[(table[:, _CONFIRMED] > 0) & self._alive(table, int(stamp))]
        if table.shape[0] == 0:
            return empty_tracks(stamp)
        c = self.config
        dt_s = (stamp - table[:, _T_US]) / US_PER_S
        state, cov = cv_kalman.predict(table[:, _STATE], table[:, _COV], dt_s, self._accel_var)
        hits = table[:, _HITS]
        cls = classify_radar_tracks(table[:, _RCS_SUM] / hits, hits, table[:, _MAX_SPEED], c.classes)
        cls_index = cls.astype(np.intp)
        speed = np.hypot(state[:, 2], state[:, 3])
        moving = speed > c.min_speed_for_yaw_mps
        out = np.empty((table.shape[0], len(TRACK_COLUMNS)))
        out[:, _OUT_X : _OUT_VY + 1] = state
        out[:, _OUT_LENGTH] = _LENGTH_BY_CLASS[cls_index]
        out[:, _OUT_WIDTH] = _WIDTH_BY_CLASS[cls_index]
        out[:, _OUT_YAW] = np.where(moving, np.arctan2(state[:, 3], state[:, 2]), table[:, _YAW])
        out[:, _OUT_CLASS] = cls
        out[:, _OUT_STD] = np.sqrt(cov[:, 0])
        out[:, _OUT_AGE] = (stamp - table[:, _BORN_US]) / US_PER_S
        return TrackedObjects(stamp=stamp, ids=table[:, _ID].astype(np.int64), table=out)

    # --------------------------------------------------------------------------------------------
    def _sensor_bit(self, sensor_id: str) -> float:
        bit = self._sensor_bits.get(sensor_id)
        if bit is None:
            if len(self._sensor_bits) >= _MAX_SENSORS:
                raise MessageError(
                    f"RadarFrame.sensor_id: expected at most {_MAX_SENSORS} distinct radars, got "
                    f"{sensor_id!r} after {sorted(self._sensor_bits)}"
                )
            bit = self._sensor_bits[sensor_id] = len(self._sensor_bits)
        return float(1 << bit)

    def _to_map(self, objects: np.ndarray, map_from_sensor: SE2) -> tuple[np.ndarray, np.ndarray]:
        """Detections as (D, 4) map-frame x, y, vx, vy and their (D,) position variances."""
        c, s = math.cos(map_from_sensor.yaw_rad), math.sin(map_from_sensor.yaw_rad)
        x, y, vx, vy = objects[:, 0], objects[:, 1], objects[:, 2], objects[:, 3]
        z = np.empty((objects.shape[0], 4))
        z[:, 0] = map_from_sensor.x_m + c * x - s * y
        z[:, 1] = map_from_sensor.y_m + s * x + c * y
        z[:, 2] = c * vx - s * vy
        z[:, 3] = s * vx + c * vy
        pos_std = self.config.pos_noise_m + self.config.pos_noise_per_m * np.hypot(x, y)
        return z, pos_std * pos_std

    def _associate(
        self, state: np.ndarray, cov: np.ndarray, z: np.ndarray, pos_var: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Hungarian assignment on the negative log-likelihood of gated pairs."""
        c = self.config
        d2, nll, dist2 = cv_kalman.gate_costs(state, cov, z, pos_var, self._vel_var)
        feasible = (d2 <= c.gate_chi2) & (dist2 <= c.gate_m * c.gate_m)
        if not feasible.any():
            empty = np.zeros(0, dtype=np.intp)
            return empty, empty
        rows = np.flatnonzero(feasible.any(axis=1))
        cols = np.flatnonzero(feasible.any(axis=0))
        if len(rows) == 1 and len(cols) == 1:
            return rows, cols
        # A flat penalty on gated-out pairs keeps the problem square-free for SciPy; such pairs are
        # dropped afterwards, so they never update a track.
        cost = np.where(feasible, nll, _INFEASIBLE)[np.ix_(rows, cols)]
        r, k = linear_sum_assignment(cost)
        keep = cost[r, k] < _INFEASIBLE
        return rows[r[keep]], cols[k[keep]]

    def _correct(
        self,
        tracks: np.ndarray,
        dets: np.ndarray,
        pred_state: np.ndarray,
        pred_cov: np.ndarray,
        z: np.ndarray,
        pos_var: np.ndarray,
        objects: np.ndarray,
        t_us: int,
    ) -> None:
        c = self.config
        rows = self._table[tracks]
        new_state, new_cov = cv_kalman.update(
            pred_state[tracks], pred_cov[tracks], z[dets], pos_var[dets], self._vel_var
        )
        # A track already past this frame's stamp takes the older detection as if it were its newest
        # and is predicted forward again. For a constant-velocity model the mean is close to a true
        # rollback; the covariance is slightly inflated (process noise counted over the gap twice).
        ahead_s = np.maximum(rows[:, _T_US] - t_us, 0.0) / US_PER_S
        if ahead_s.any():
            new_state, new_cov = cv_kalman.predict(new_state, new_cov, ahead_s, self._accel_var)
        rows[:, _STATE] = new_state
        rows[:, _COV] = new_cov
        np.maximum(rows[:, _T_US], t_us, out=rows[:, _T_US])
        np.maximum(rows[:, _SEEN_US], t_us, out=rows[:, _SEEN_US])
        rows[:, _HITS] += 1.0
        rows[:, _RCS_SUM] += objects[dets, 4]
        confirmed = (rows[:, _CONFIRMED] > 0) | (rows[:, _HITS] >= c.confirm_hits)
        rows[:, _CONFIRMED] = confirmed
        speed = np.hypot(new_state[:, 2], new_state[:, 3])
        # Speed evidence for the class counts only once confirmed: a newborn's velocity is one raw,
        # noisy measurement.
        rows[confirmed, _MAX_SPEED] = np.maximum(rows[confirmed, _MAX_SPEED], speed[confirmed])
        moving = speed > c.min_speed_for_yaw_mps
        rows[moving, _YAW] = np.arctan2(new_state[moving, 3], new_state[moving, 2])
        self._table[tracks] = rows

    def _count_chances(self, matched_tracks: np.ndarray, bit: float) -> None:
        table = self._table
        if not table.shape[0]:
            return
        sensors = table[:, _SENSORS].astype(np.int64)
        ibit = int(bit)
        sensors[matched_tracks] |= ibit
        table[:, _SENSORS] = sensors
        table[:, _CHANCES] += (sensors & ibit) > 0

    def _birth(
        self,
        z: np.ndarray,
        pos_var: np.ndarray,
        objects: np.ndarray,
        matched_dets: np.ndarray,
        t_us: int,
        bit: float,
    ) -> None:
        c = self.config
        free = np.ones(len(z), dtype=bool)
        free[matched_dets] = False
        born = np.flatnonzero(free)[: max(c.max_tracks - self._table.shape[0], 0)]
        if not len(born):
            return
        rows = np.zeros((len(born), _NCOL))
        rows[:, _STATE] = z[born]
        rows[:, _PP] = pos_var[born]
        rows[:, _VV] = self._vel_var
        rows[:, [_T_US, _BORN_US, _SEEN_US]] = float(t_us)
        rows[:, _HITS] = 1.0
        rows[:, _CHANCES] = 1.0
        rows[:, _CONFIRMED] = 1.0 if c.confirm_hits <= 1 else 0.0
        rows[:, _SENSORS] = bit
        # A still newborn has no heading to show; 0 (map +x) is as good a guess as any.
        moving = np.hypot(z[born, 2], z[born, 3]) > c.min_speed_for_yaw_mps
        rows[:, _YAW] = np.where(moving, np.arctan2(z[born, 3], z[born, 2]), 0.0)
        rows[:, _RCS_SUM] = objects[born, 4]
        rows[:, _ID] = np.arange(self._next_id, self._next_id + len(born))
        self._next_id += len(born)
        self._table = np.concatenate((self._table, rows))

    def _alive(self, table: np.ndarray, now_us: int) -> np.ndarray:
        """Tracks seen within ``t_expire_s``, or confirmed ones held in the blind zone (see config)."""
        c = self.config
        unseen_us = now_us - table[:, _SEEN_US]
        alive = unseen_us <= c.t_expire_s * US_PER_S
        held = ~alive & (table[:, _CONFIRMED] > 0) & (unseen_us <= c.blind_zone_hold_s * US_PER_S)
        if held.any():
            rows = table[held]
            state, _ = cv_kalman.predict(
                rows[:, _STATE], rows[:, _COV], (now_us - rows[:, _T_US]) / US_PER_S, self._accel_var
            )
            alive[held] = self._in_blind_zone(state[:, :2])
        return alive

    def _in_blind_zone(self, xy: np.ndarray) -> np.ndarray:
        """(N,) True where a map point is near a radar yet outside every radar's field of view."""
        near = np.zeros(len(xy), dtype=bool)
        seen = np.zeros(len(xy), dtype=bool)
        if self._map_from_base is None:
            return near
        for mount in self._mounts.values():
            sensor = self._map_from_base.compose(mount)
            c, s = math.cos(sensor.yaw_rad), math.sin(sensor.yaw_rad)
            dx, dy = xy[:, 0] - sensor.x_m, xy[:, 1] - sensor.y_m
            ahead, left = c * dx + s * dy, -s * dx + c * dy
            near |= np.hypot(ahead, left) <= self.config.blind_zone_range_m
            seen |= np.abs(np.arctan2(left, ahead)) <= self.config.sensor_half_fov_rad
        return near & ~seen

    def _prune(self) -> None:
        c = self.config
        table = self._table
        if not table.shape[0]:
            return
        fresh = self._alive(table, self._latest_us)
        hopeless = (table[:, _CONFIRMED] == 0) & (
            table[:, _CHANCES] - table[:, _HITS] > c.confirm_window - c.confirm_hits
        )
        keep = fresh & ~hopeless
        if not keep.all():
            self._table = table[keep]
