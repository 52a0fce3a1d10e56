"""aUToTrack (aUToronto 6.3): 3D box multi-object tracker with trial/full lifecycle, class HMM and rollback.

One update per detection message (:class:`DetectedBoxes`, from any LiDAR, radar-fused or other source):

1. every track is predicted to the message's capture stamp (:mod:`lastmile.tracking.box_kalman`);
2. detections are associated to tracks on the weighted, gated cost of
   :mod:`lastmile.tracking.association` (Hungarian by default);
3. matched tracks get a Kalman update (with the radar Doppler velocity where the box carries one),
   a size update, a class-HMM update, and take the detection's score and attributes;
4. unmatched detections scoring at least their class's ``birth_min_score`` start *trial* tracks;
5. lifecycle: a trial track becomes *full* once it has been detected over ``t_birth_s``; a full track
   not detected for more than ``t_expire_s`` is demoted to trial (and promoted again on its next
   detection); a track not detected for more than ``t_prune_s`` (``t_expire_s`` for one that was never
   full) is deleted. Only full tracks are published.

Lifecycle with several sources: a track is "undetected" only over time every live source has
reported. Demotion and pruning count from the oldest of the sources' newest stamps (sources silent for
more than ``source_timeout_s`` excluded), so a sensor whose frames run late or stamp less often does not
get the objects only it sees demoted before its frames are in. With one source this is the message's
stamp. The horizon depends only on messages in capture order, so rollback keeps results independent of
arrival order.

Rollback: messages (detections, and camera class evidence, which sorts after the detections of its
stamp) are kept in capture order (stamp, kind, source name) with the tracker state after each. A message
older than the newest processed one rolls the tracker back to the state just before its stamp and
replays it and every later message, so arrival order does not change the result. Published ids are
kept through replays by :mod:`lastmile.tracking.published_ids`.
Nothing is dropped: a message older than the retained window (``rollback_window_s``) is replayed from
the oldest retained state, its tracks retrodicted to its stamp (counted in ``late_beyond_window``).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field, fields

import numpy as np

from lastmile.core.box3d import BOX3D_COLUMNS
from lastmile.core.boxes3d import TRACK_BOX_COLUMNS, DetectedBoxes, TrackedBoxes
from lastmile.core.errors import MessageError
from lastmile.core.stamp import Stamp
from lastmile.tracking import box_kalman
from lastmile.tracking.association import assign, association_cost
from lastmile.tracking.autotrack_config import (
    AutoTrackConfig,
    ClassParams,
    class_table,
    default_class_params,
)
from lastmile.tracking.class_hmm import (
    N_CLASSES,
    hmm_update,
    initial_prob,
    match_camera_detections,
)
from lastmile.tracking.published_ids import PublishedIds

__all__ = ["AutoTrack", "AutoTrackConfig", "ClassParams", "default_class_params"]

_US = 1e-6
SCORE_PRIOR_DETECTIONS = 1.0
"""Weight, in detections, of the even-odds prior in the ``"mean"`` track score (fixed, not tuned)."""


@dataclass(slots=True)
class _Tracks:
    """All live tracks, struct-of-arrays (copied whole for rollback snapshots)."""

    ids: np.ndarray
    x: np.ndarray
    p: np.ndarray
    size: np.ndarray
    stamp_us: np.ndarray
    first_det_us: np.ndarray
    last_det_us: np.ndarray
    full: np.ndarray
    ever_full: np.ndarray
    class_prob: np.ndarray
    score: np.ndarray
    evidence: np.ndarray  # sum of the scores of the track's detections
    miss_log: np.ndarray  # sum of softplus(score): -log of the probability that every detection was false
    n_detections: np.ndarray  # how many detections the track has had
    attributes: np.ndarray
    birth_source: np.ndarray  # code of the source whose detection started the track
    birth_index: np.ndarray  # that detection's row in its message
    next_id: int
    source_latest_us: dict[str, int] = field(default_factory=dict)  # newest stamp per source so far

    @staticmethod
    def empty(n_attributes: int) -> _Tracks:
        return _Tracks(
            ids=np.zeros(0, np.int64),
            x=np.zeros((0, box_kalman.STATE_DIM)),
            p=np.zeros((0, box_kalman.STATE_DIM, box_kalman.STATE_DIM)),
            size=np.zeros((0, 3)),
            stamp_us=np.zeros(0, np.int64),
            first_det_us=np.zeros(0, np.int64),
            last_det_us=np.zeros(0, np.int64),
            full=np.zeros(0, bool),
            ever_full=np.zeros(0, bool),
            class_prob=np.zeros((0, N_CLASSES)),
            score=np.zeros(0),
            evidence=np.zeros(0),
            miss_log=np.zeros(0),
            n_detections=np.zeros(0, np.int64),
            attributes=np.zeros((0, n_attributes)),
            birth_source=np.zeros(0, np.int64),
            birth_index=np.zeros(0, np.int64),
            next_id=0,
        )

    def copy(self) -> _Tracks:
        arrays = {f: getattr(self, f).copy() for f in _ARRAY_FIELDS}
        return _Tracks(**arrays, next_id=self.next_id, source_latest_us=dict(self.source_latest_us))

    def keep(self, mask: np.ndarray) -> None:
        for f in _ARRAY_FIELDS:
            setattr(self, f, getattr(self, f)[mask])

    def append(self, other: _Tracks) -> None:
        for f in _ARRAY_FIELDS:
            setattr(self, f, np.concatenate([getattr(self, f), getattr(other, f)]))

    def boxes(self) -> np.ndarray:
        """(N, 7) boxes of the current states."""
        return np.column_stack([self.x[:, 0:3], self.size, self.x[:, 3]])


@dataclass(frozen=True, slots=True)
class _CameraEvidence:
    """2D camera detections queued with the detection messages (class evidence only)."""

    stamp_us: int
    boxes: np.ndarray  # (M, 4) image boxes
    classes: np.ndarray  # (M,) ObjectClass values
    camera_from_frame: np.ndarray  # (4, 4)
    intrinsics: np.ndarray  # (3, 3)


_ARRAY_FIELDS = tuple(f.name for f in fields(_Tracks) if f.name not in ("next_id", "source_latest_us"))


class AutoTrack:
    """The tracker. Feed :meth:`update` with detection messages in any order; read :meth:`tracks`."""

    def __init__(self, config: AutoTrackConfig | None = None, *, n_attributes: int = 0) -> None:
        self.config = config or AutoTrackConfig()
        self._ct = class_table(self.config)
        self._n_attr = n_attributes
        self._t = _Tracks.empty(n_attributes)
        self._queue: list[tuple[tuple[int, int, str], DetectedBoxes | _CameraEvidence]] = []
        self._states: list[_Tracks] = []  # state after each queued message
        self._base = self._t.copy()  # state before the first queued message
        self.late_beyond_window = 0
        self.rollbacks = 0
        self.refused_births = 0
        self._source_codes: dict[str, int] = {}
        # Not part of the rolled-back state: which ids have been published is a fact replays don't undo.
        self.published_ids = PublishedIds()

    def __len__(self) -> int:
        return int(self._t.ids.shape[0])

    # ----------------------------------------------------------------- rollback bookkeeping
    def update(self, msg: DetectedBoxes) -> None:
        """Process one detection message (late ones roll the tracker back and replay).

        Raises:
            MessageError: the message's attribute width differs from the tracker's ``n_attributes``.
        """
        if msg.attributes.shape[1] != self._n_attr:
            raise MessageError(
                f"DetectedBoxes.attributes: expected {self._n_attr} columns, got {msg.attributes.shape[1]}"
            )
        self._enqueue((int(msg.stamp), 0, msg.source), msg)

    def _enqueue(self, key: tuple[int, int, str], item: DetectedBoxes | _CameraEvidence) -> int:
        """Apply ``item`` in capture order (rolling back and replaying if it is late); returns its result."""
        if not self._queue or key >= self._queue[-1][0]:
            result = self._apply(item)
            self._queue.append((key, item))
            self._states.append(self._t.copy())
        else:
            self.rollbacks += 1
            before = self._published_snapshot()
            pos = bisect.bisect_right([k for k, _ in self._queue], key)
            if pos == 0:
                self.late_beyond_window += int(
                    self._queue[0][0][0] - key[0] > self.config.rollback_window_s / _US
                )
            self._t = (self._states[pos - 1] if pos > 0 else self._base).copy()
            self._queue.insert(pos, (key, item))
            del self._states[pos:]
            result = 0
            for i, (_, m) in enumerate(self._queue[pos:]):
                r = self._apply(m)
                result = r if i == 0 else result
                self._states.append(self._t.copy())
            keys, xy, vxy, expires = before
            self.published_ids.retire(
                keys, xy, vxy, self._queue[-1][0][0], expires, set(self._keys(np.nonzero(self._t.full)[0]))
            )
        self._trim()
        self._assign_public_ids()
        return result

    def _apply(self, item: DetectedBoxes | _CameraEvidence) -> int:
        if isinstance(item, _CameraEvidence):
            return self._camera_step(item)
        self._step(item)
        return 0

    # ----------------------------------------------------------------- published ids
    def _source_code(self, source: str) -> int:
        return self._source_codes.setdefault(source, len(self._source_codes))

    def _keys(self, rows: np.ndarray) -> list[tuple[int, int, int]]:
        t = self._t
        return list(
            zip(
                t.first_det_us[rows].tolist(),
                t.birth_source[rows].tolist(),
                t.birth_index[rows].tolist(),
                strict=True,
            )
        )

    def _published_snapshot(self) -> tuple[list[tuple[int, int, int]], np.ndarray, np.ndarray, np.ndarray]:
        """Keys, positions, velocities and id expiry times of the published tracks (before a replay).

        A track a replay retracts keeps its id reserved for as long as it could have coasted had it
        stayed: its class's ``t_prune_s`` after it was last published (the tracker's current stamp),
        plus the lag of the oldest source behind that stamp, since undetected time is only counted up to
        that source's newest stamp (see :meth:`_horizon`).
        """
        t = self._t
        sel = np.nonzero(t.full)[0]
        cls = np.argmax(t.class_prob[sel], axis=1)
        lag = t.stamp_us[sel] - self._horizon(int(t.stamp_us[sel].max())) if sel.size else 0
        expires = t.stamp_us[sel] + lag + np.round(self._params("t_prune_s", cls) / _US).astype(np.int64)
        return self._keys(sel), t.x[sel, 0:2], t.x[sel, 4:6], expires

    def _assign_public_ids(self) -> None:
        t = self._t
        sel = np.nonzero(t.full)[0]
        cls = np.argmax(t.class_prob[sel], axis=1)
        self.published_ids.assign(
            self._keys(sel), t.x[sel, 0:2], self._params("gate_m", cls), self._queue[-1][0][0]
        )

    def _trim(self) -> None:
        newest = self._queue[-1][0][0]
        horizon = newest - self.config.rollback_window_s / _US
        cut = 0
        while cut < len(self._queue) - 1 and self._queue[cut][0][0] < horizon:
            cut += 1
        if cut:
            self._base = self._states[cut - 1]
            del self._queue[:cut]
            del self._states[:cut]
        if len(self.published_ids) > 2 * self._t.ids.size + 64:
            # Ids of hypotheses gone from the current state and the oldest one a replay can restore.
            keep = set(self._keys(np.arange(self._t.ids.size)))
            keep.update(zip(self._base.first_det_us.tolist(), self._base.birth_source.tolist(),
                            self._base.birth_index.tolist(), strict=True))  # fmt: skip
            self.published_ids.forget_except(keep)

    # ----------------------------------------------------------------- one message
    def _params(self, name: str, cls: np.ndarray) -> np.ndarray:
        return self._ct[name][cls]

    def _step(self, msg: DetectedBoxes) -> None:
        cfg = self.config
        t = self._t
        now = int(msg.stamp)
        if t.ids.size:
            cls = np.argmax(t.class_prob, axis=1)
            dt = (now - t.stamp_us) * _US
            t.x, t.p = box_kalman.predict(
                t.x, t.p, dt, self._params("accel_std_mps2", cls), self._params("yaw_accel_std_radps2", cls)
            )
            t.stamp_us = np.full_like(t.stamp_us, now)
        det_boxes = msg.boxes
        det_cls = msg.class_id
        cost = association_cost(
            t.boxes(), t.class_prob, det_boxes, det_cls, self._params("gate_m", det_cls), cfg.association
        )
        ti, di = assign(cost, cfg.association.method)
        if ti.size:
            self._update_matched(ti, di, msg)
        unmatched = np.ones(len(msg), bool)
        unmatched[di] = False
        born = unmatched & (msg.score >= self._params("birth_min_score", det_cls))
        self._birth(np.nonzero(born)[0], msg)
        t.source_latest_us[msg.source] = max(now, t.source_latest_us.get(msg.source, now))
        self._lifecycle(now, self._horizon(now))

    def _horizon(self, now: int) -> int:
        """Oldest of the live sources' newest stamps: undetected time is counted up to here."""
        timeout = now - self.config.source_timeout_s / _US
        return min((v for v in self._t.source_latest_us.values() if v >= timeout or v == now), default=now)

    def _update_matched(self, ti: np.ndarray, di: np.ndarray, msg: DetectedBoxes) -> None:
        cfg = self.config
        t = self._t
        b = msg.boxes[di]
        cls = msg.class_id[di]
        pos_var = self._params("pos_std_m", cls) ** 2
        yaw_var = self._params("yaw_std_rad", cls) ** 2
        has_v = msg.has_velocity[di]
        for with_v in (False, True):
            sel = has_v == with_v
            if not np.any(sel):
                continue
            z = b[sel][:, [0, 1, 2, 6]]
            r = np.column_stack([pos_var[sel], pos_var[sel], pos_var[sel], yaw_var[sel]])
            if with_v:
                z = np.column_stack([z, msg.velocity_mps[di[sel]]])
                vv = np.full(int(sel.sum()), cfg.radar_velocity_std_mps**2)
                r = np.column_stack([r, vv, vv])
            rows = ti[sel]
            t.x[rows], t.p[rows] = box_kalman.update(t.x[rows], t.p[rows], z, r, with_v)
        t.size[ti] += cfg.size_gain * (b[:, 3:6] - t.size[ti])
        t.class_prob[ti] = hmm_update(t.class_prob[ti], cls, cfg.hmm.lidar_accuracy, cfg.hmm.switch_prob)
        t.score[ti] = msg.score[di]
        t.evidence[ti] += msg.score[di]
        t.miss_log[ti] += np.logaddexp(0.0, msg.score[di])
        t.n_detections[ti] += 1
        t.attributes[ti] = msg.attributes[di]
        t.last_det_us[ti] = int(msg.stamp)

    def _birth(self, di: np.ndarray, msg: DetectedBoxes) -> None:
        cfg = self.config
        t = self._t
        room = cfg.max_tracks - t.ids.size
        if di.size > room:
            self.refused_births += int(di.size - max(room, 0))
            di = di[: max(room, 0)]
        n = di.size
        if n == 0:
            return
        b = msg.boxes[di]
        cls = msg.class_id[di]
        x = np.zeros((n, box_kalman.STATE_DIM))
        x[:, 0:3] = b[:, 0:3]
        x[:, 3] = b[:, 6]
        p = np.zeros((n, box_kalman.STATE_DIM, box_kalman.STATE_DIM))
        pos_var = self._params("pos_std_m", cls) ** 2
        for k in range(3):
            p[:, k, k] = pos_var
        p[:, 3, 3] = self._params("yaw_std_rad", cls) ** 2
        v_var = self._params("init_speed_std_mps", cls) ** 2
        p[:, 4, 4] = v_var
        p[:, 5, 5] = v_var
        p[:, 6, 6] = 0.5**2
        has_v = msg.has_velocity[di]
        x[has_v, 4:6] = msg.velocity_mps[di[has_v]]
        p[has_v, 4, 4] = cfg.radar_velocity_std_mps**2
        p[has_v, 5, 5] = cfg.radar_velocity_std_mps**2
        now = int(msg.stamp)
        new = _Tracks(
            ids=np.arange(t.next_id, t.next_id + n, dtype=np.int64),
            x=x,
            p=p,
            size=b[:, 3:6].copy(),
            stamp_us=np.full(n, now, np.int64),
            first_det_us=np.full(n, now, np.int64),
            last_det_us=np.full(n, now, np.int64),
            full=np.zeros(n, bool),
            ever_full=np.zeros(n, bool),
            class_prob=initial_prob(cls, cfg.hmm.lidar_accuracy),
            score=msg.score[di].astype(np.float64),
            evidence=msg.score[di].astype(np.float64),
            miss_log=np.logaddexp(0.0, msg.score[di].astype(np.float64)),
            n_detections=np.ones(n, np.int64),
            attributes=msg.attributes[di].copy(),
            birth_source=np.full(n, self._source_code(msg.source), np.int64),
            birth_index=di.astype(np.int64),
            next_id=0,
        )
        t.append(new)
        t.next_id += n

    def _lifecycle(self, now: int, horizon: int) -> None:
        """Promote tracks detected at ``now``; demote and prune by the time undetected at ``horizon``."""
        t = self._t
        if t.ids.size == 0:
            return
        cls = np.argmax(t.class_prob, axis=1)
        since = (horizon - t.last_det_us) * _US
        detected_now = t.last_det_us == now
        span = (t.last_det_us - t.first_det_us) * _US
        born = (span >= self._params("t_birth_s", cls) - 1e-9) & (
            t.evidence >= self._params("birth_min_evidence", cls)
        )
        promote = detected_now & (t.ever_full | born)
        t.full |= promote
        t.ever_full |= promote
        t.full &= since <= self._params("t_expire_s", cls) + 1e-9
        limit = np.where(t.ever_full, self._params("t_prune_s", cls), self._params("t_expire_s", cls))
        t.keep(since <= limit + 1e-9)

    # ----------------------------------------------------------------- camera evidence and output
    def update_classes_from_camera(
        self,
        stamp: Stamp,
        camera_boxes: np.ndarray,
        camera_class: np.ndarray,
        camera_from_frame: np.ndarray,
        intrinsics: np.ndarray,
        *,
        source: str = "camera",
    ) -> int:
        """Update track classes (only) from 2D camera detections matched by projection; returns matches.

        The evidence joins the capture-ordered queue like a detection message, so a later rollback replays
        it at its stamp instead of losing it, and a late camera frame rolls back like a late LiDAR one.
        Tracks are predicted to ``stamp`` for the projection only; their states are left unchanged.

        Raises:
            MessageError: not one class per camera box.
        """
        camera_class = np.array(camera_class, dtype=np.int64)
        camera_boxes = np.array(camera_boxes, dtype=np.float64)
        if camera_class.shape[0] != camera_boxes.shape[0]:
            raise MessageError(
                f"camera_class: expected one class per camera box ({camera_boxes.shape[0]}), "
                f"got {camera_class.shape[0]}"
            )
        ev = _CameraEvidence(
            stamp_us=int(stamp),
            boxes=camera_boxes,
            classes=camera_class,
            camera_from_frame=np.array(camera_from_frame, dtype=np.float64),
            intrinsics=np.array(intrinsics, dtype=np.float64),
        )
        # Evidence sorts after the detection messages of its stamp: it labels tracks, it never starts one.
        return self._enqueue((int(stamp), 1, source), ev)

    def _camera_step(self, ev: _CameraEvidence) -> int:
        ti, ci = match_camera_detections(
            self._predicted_boxes(ev.stamp_us),
            ev.boxes,
            ev.camera_from_frame,
            ev.intrinsics,
            self.config.hmm.min_camera_iou,
        )
        if ti.size:
            self._t.class_prob[ti] = hmm_update(
                self._t.class_prob[ti],
                ev.classes[ci],
                self.config.hmm.camera_accuracy,
                self.config.hmm.switch_prob,
            )
        return int(ti.size)

    def _predicted_boxes(self, stamp: int) -> np.ndarray:
        t = self._t
        cls = np.argmax(t.class_prob, axis=1)
        x, _ = box_kalman.predict(
            t.x, t.p, (stamp - t.stamp_us) * _US,
            self._params("accel_std_mps2", cls), self._params("yaw_accel_std_radps2", cls),
        )  # fmt: skip
        return np.column_stack([x[:, 0:3], t.size, x[:, 3]])

    def _track_score(self, sel: np.ndarray) -> np.ndarray:
        """Confidence of the tracks ``sel`` before the coasting penalty (``AutoTrackConfig.track_score``)."""
        t = self._t
        mode = self.config.track_score
        if mode == "last":
            return t.score[sel]
        if mode == "evidence":
            return t.evidence[sel]
        if mode == "refined":
            # Benbarka et al.'s multiplicative-complement update, c <- 1 - (1 - c)(1 - p), over the
            # detections' probabilities p = sigmoid(score): 1 - c = prod(1 - p) = exp(-miss_log).
            # Published as the log-odds of c, log(expm1(miss_log)), on the other definitions' scale.
            m = np.maximum(t.miss_log[sel], 1e-300)
            return m + np.log(-np.expm1(-m))
        # "mean": the detections' mean score shrunk towards the prior (log-odds 0, even odds) with the
        # weight of SCORE_PRIOR_DETECTIONS detections, so a track of one or two detections cannot rank
        # above a long run of the same scores.
        return t.evidence[sel] / (t.n_detections[sel] + SCORE_PRIOR_DETECTIONS)

    def tracks(self, stamp: Stamp) -> TrackedBoxes:
        """Full tracks predicted to ``stamp`` (the tracker's state is not changed)."""
        t = self._t
        sel = np.nonzero(t.full)[0]
        cls = np.argmax(t.class_prob[sel], axis=1)
        dt = (int(stamp) - t.stamp_us[sel]) * _US
        if np.any(dt != 0.0):
            x, p = box_kalman.predict(
                t.x[sel], t.p[sel], dt,
                self._params("accel_std_mps2", cls), self._params("yaw_accel_std_radps2", cls),
            )  # fmt: skip
        else:  # asked at the last update's stamp: nothing to predict
            x, p = t.x[sel], t.p[sel]
        since = (int(stamp) - t.last_det_us[sel]) * _US
        table = np.column_stack(
            [
                x[:, 0:3],
                t.size[sel],
                x[:, 3],
                x[:, 4:7],
                np.sqrt(0.5 * (p[:, 0, 0] + p[:, 1, 1])),
                (int(stamp) - t.first_det_us[sel]) * _US,
            ]
        )
        assert table.shape[1] == len(TRACK_BOX_COLUMNS) and len(BOX3D_COLUMNS) == 7
        return TrackedBoxes(
            stamp=stamp,
            ids=self.published_ids.ids_of(self._keys(sel)),
            table=table.reshape(-1, len(TRACK_BOX_COLUMNS)),
            class_id=cls,
            class_prob=t.class_prob[sel],
            score=self._track_score(sel) - self.config.coast_score_penalty_per_s * np.maximum(since, 0.0),
            updated=since == 0.0,
            attributes=t.attributes[sel],
        )
