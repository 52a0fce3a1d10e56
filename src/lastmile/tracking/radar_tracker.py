"""Radar object tracker: Hungarian association, constant-velocity Kalman filters, M-of-N confirmation.

Radar object lists carry position and over-ground velocity, so the filter measures all four states.
Several radars feed one tracker; frames are applied in the order given (full out-of-order rollback is
issue #4's aUToTrack design).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from lastmile.core.errors import MessageError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects, empty_tracks
from lastmile.core.sensor_frames import RadarFrame
from lastmile.core.stamp import Stamp

# Footprints by class (length, width) in m: radar object lists carry no extent.
_SIZE = {
    ObjectClass.UNKNOWN: (1.0, 1.0),
    ObjectClass.CAR: (4.5, 1.8),
    ObjectClass.PEDESTRIAN: (0.5, 0.5),
    ObjectClass.CYCLIST: (1.8, 0.6),
    ObjectClass.ANIMAL: (0.5, 0.3),
}


@dataclass(frozen=True, slots=True, kw_only=True)
class RadarTrackerConfig:
    """Tracker parameters.

    Attributes:
        gate_m: largest position distance at which a detection may update a track.
        accel_noise_mps2: white-acceleration process noise of the constant-velocity model.
        pos_noise_m, vel_noise_mps: measurement noise (one sigma) of radar positions and velocities.
        confirm_hits, confirm_window: a track is confirmed after this many hits in its first updates.
        expire_s: a track unseen this long is deleted.
        max_tracks: hard bound on live tracks (clutter storms must not grow memory without limit).
    """

    gate_m: float = 2.5
    accel_noise_mps2: float = 1.5
    pos_noise_m: float = 0.3
    vel_noise_mps: float = 0.3
    confirm_hits: int = 3
    confirm_window: int = 5
    expire_s: float = 0.6
    max_tracks: int = 200


@dataclass(slots=True)
class _Track:
    id: int
    x: np.ndarray  # (4,) x, y, vx, vy
    p: np.ndarray  # (4, 4)
    stamp_us: int
    born_us: int
    last_seen_us: int
    hits: int = 1
    updates: int = 1
    confirmed: bool = False
    rcs_sum: float = 0.0
    yaw_rad: float = 0.0
    max_speed_mps: float = 0.0

    def cls(self) -> ObjectClass:
        rcs = self.rcs_sum / max(self.hits, 1)
        if rcs >= 2.0:
            return ObjectClass.CAR
        if rcs < -11.0 and self.max_speed_mps < 1.0:
            return ObjectClass.ANIMAL
        if -10.0 <= rcs < 1.0:
            return ObjectClass.CYCLIST if self.max_speed_mps > 3.0 else ObjectClass.PEDESTRIAN
        return ObjectClass.UNKNOWN


@dataclass
class RadarObjectTracker:
    """Tracks in the map frame from radar object lists."""

    config: RadarTrackerConfig = field(default_factory=RadarTrackerConfig)
    _tracks: list[_Track] = field(default_factory=list)
    _next_id: int = 1

    def update(self, frame: RadarFrame, map_from_base: SE2, base_from_sensor: SE2) -> None:
        """Associate one radar frame with the tracks and update them."""
        if frame.stamp < 0:
            raise MessageError(f"RadarFrame.stamp: expected a non-negative stamp, got {frame.stamp}")
        c = self.config
        t_us = int(frame.stamp)
        map_from_sensor = map_from_base.compose(base_from_sensor)
        obj = frame.objects
        if len(obj):
            pos = map_from_sensor.apply_points(obj[:, 0:2])
            cs, sn = math.cos(map_from_sensor.yaw_rad), math.sin(map_from_sensor.yaw_rad)
            vel = np.c_[cs * obj[:, 2] - sn * obj[:, 3], sn * obj[:, 2] + cs * obj[:, 3]]
            z = np.c_[pos, vel]
        else:
            z = np.zeros((0, 4))
        predicted = [self._predicted(t, t_us) for t in self._tracks]
        assigned: set[int] = set()
        if len(z) and predicted:
            cost = np.full((len(predicted), len(z)), 1e6)
            for i, (x, _) in enumerate(predicted):
                d = np.hypot(z[:, 0] - x[0], z[:, 1] - x[1])
                cost[i] = np.where(d < c.gate_m, d, 1e6)
            rows, cols = linear_sum_assignment(cost)
            for i, j in zip(rows.tolist(), cols.tolist(), strict=True):
                if cost[i, j] >= 1e6:
                    continue
                self._correct(self._tracks[i], predicted[i], z[j], float(obj[j, 4]), t_us)
                assigned.add(j)
        for j in range(len(z)):
            if j not in assigned and len(self._tracks) < c.max_tracks:
                self._birth(z[j], float(obj[j, 4]), t_us)
        for t in self._tracks:
            if t.last_seen_us != t_us and t.stamp_us <= t_us:
                t.updates += 1
        self._tracks = [
            t
            for t in self._tracks
            if (t_us - t.last_seen_us) / 1e6 <= c.expire_s
            and (t.confirmed or t.updates < c.confirm_window or t.hits >= c.confirm_hits)
        ]

    def _predicted(self, t: _Track, t_us: int) -> tuple[np.ndarray, np.ndarray]:
        # A frame older than the track's state predicts it backward: an approximation until rollback.
        # TODO(#4): rollback
        dt = (t_us - t.stamp_us) / 1e6
        f = np.eye(4)
        f[0, 2] = f[1, 3] = dt
        q = self.config.accel_noise_mps2**2
        adt = abs(dt)
        g = np.array([[adt**2 / 2, 0], [0, adt**2 / 2], [adt, 0], [0, adt]])
        return f @ t.x, f @ t.p @ f.T + q * (g @ g.T)

    def _correct(
        self, t: _Track, pred: tuple[np.ndarray, np.ndarray], z: np.ndarray, rcs: float, t_us: int
    ) -> None:
        c = self.config
        x, p = pred
        r = np.diag([c.pos_noise_m**2] * 2 + [c.vel_noise_mps**2] * 2)
        k = p @ np.linalg.inv(p + r)
        t.x = x + k @ (z - x)
        t.p = (np.eye(4) - k) @ p
        t.stamp_us = max(t.stamp_us, t_us)
        t.last_seen_us = max(t.last_seen_us, t_us)
        t.hits += 1
        t.updates += 1
        t.rcs_sum += rcs
        speed = math.hypot(t.x[2], t.x[3])
        t.max_speed_mps = max(t.max_speed_mps, speed)
        if speed > 0.5:
            t.yaw_rad = math.atan2(t.x[3], t.x[2])
        if t.hits >= c.confirm_hits:
            t.confirmed = True

    def _birth(self, z: np.ndarray, rcs: float, t_us: int) -> None:
        c = self.config
        p = np.diag([c.pos_noise_m**2] * 2 + [c.vel_noise_mps**2] * 2)
        track = _Track(self._next_id, z.copy(), p, t_us, t_us, t_us, rcs_sum=rcs)
        track.max_speed_mps = math.hypot(z[2], z[3])
        self._tracks.append(track)
        self._next_id += 1

    def tracks(self, stamp: Stamp) -> TrackedObjects:
        """Confirmed tracks predicted to ``stamp`` (map frame)."""
        rows, ids = [], []
        for t in self._tracks:
            if not t.confirmed:
                continue
            x, p = self._predicted(t, int(stamp))
            cls = t.cls()
            length, width = _SIZE[cls]
            row = [0.0] * len(TRACK_COLUMNS)
            row[0:4] = x.tolist()
            row[4:8] = [length, width, t.yaw_rad, float(cls)]
            row[8] = math.sqrt(max(p[0, 0], p[1, 1]))
            row[9] = (int(stamp) - t.born_us) / 1e6
            rows.append(row)
            ids.append(t.id)
        if not rows:
            return empty_tracks(stamp)
        return TrackedObjects(stamp=stamp, ids=np.array(ids, dtype=np.int64), table=np.array(rows))
