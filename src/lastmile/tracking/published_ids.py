"""Published track ids that survive rollback replays (aUToTrack's output labels).

Rollback makes the tracker's *state* after any set of messages independent of their arrival order. Its
*live output* is another matter: between a message's capture and its late arrival the tracker publishes
from the messages it has, and the replay that the late message triggers can revise that history. The
object keeps being tracked, but by a different track hypothesis:

- a track started by the late message's detection replaces the one started by a later detection (the
  late message saw the object first, or a frame of another sensor with the same stamp sorts before it);
- a track kept alive only because a late sensor had not reported yet is pruned by the replay, and the
  object is picked up by a successor born from one of its later detections.

A tracker numbering tracks at birth publishes those as new ids: an ID switch that in-order delivery
never shows (measured in ``benchmarks/tracking_sim.py``). This module keeps the label instead:

- a track hypothesis is named by the detection that started it, ``(stamp_us, source code, row)``, which
  replay does not change (a birth counter does: an extra birth in a late message shifts every later id);
- its public id is given once, when it is first published (full), and kept while it lives;
- a published track that a *replay* removes from the output (deleted or no longer full) is retired
  with its public id, position and velocity; for as long as it could have coasted had it stayed
  (``t_prune_s`` after it was last published, plus the lag of the slowest source behind that stamp:
  the live tracker counts undetected time only up to the oldest of the sources' newest stamps), a
  newly published track within its class's association gate of the retired one's predicted position
  takes that id (Hungarian on distance).
  If the retired track itself is published again first (it was only demoted), it keeps its id.

Only replays retire ids, so with in-order delivery nothing is inherited and ids are the tracks' own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

_US = 1e-6
TrackKey = tuple[int, int, int]  # birth stamp (us), birth source code, row of the birth detection


@dataclass(frozen=True, slots=True)
class _Retired:
    key: TrackKey
    public_id: int
    xy_m: np.ndarray  # (2,) position at stamp_us
    vxy_mps: np.ndarray  # (2,) velocity
    stamp_us: int
    expires_us: int  # when the track was last published + its class's t_prune_s


class PublishedIds:
    """Public ids of track hypotheses, kept through the replays rollback causes."""

    def __init__(self) -> None:
        self._ids: dict[TrackKey, int] = {}
        self._retired: list[_Retired] = []
        self._next = 0
        self.inherited = 0  # ids handed from a track a replay removed to its successor

    def __len__(self) -> int:
        return len(self._ids)

    def ids_of(self, keys: list[TrackKey]) -> np.ndarray:
        """(N,) int64 public ids of published tracks (every one has been through :meth:`assign`)."""
        return np.array([self._ids[k] for k in keys], np.int64)

    def retire(
        self,
        before: list[TrackKey],
        xy_m: np.ndarray,
        vxy_mps: np.ndarray,
        stamp_us: int,
        expires_us: np.ndarray,
        still_published: set[TrackKey],
    ) -> None:
        """After a replay: free the ids of tracks published before it and not any more.

        Args:
            before: keys of the tracks published before the replay.
            xy_m: (N, 2) their positions at ``stamp_us``.
            vxy_mps: (N, 2) their velocities.
            stamp_us: the stamp their states were at.
            expires_us: (N,) until when each one's id stays reserved for a successor.
            still_published: keys published after the replay.
        """
        for i, key in enumerate(before):
            if key in still_published or key not in self._ids:
                continue
            # The key keeps its id for now: if the track itself is published again first (it was only
            # demoted), it goes on under its id and the retired entry is dropped.
            self._retired.append(
                _Retired(key, self._ids[key], xy_m[i].copy(), vxy_mps[i].copy(), stamp_us, int(expires_us[i]))
            )

    def assign(self, keys: list[TrackKey], xy_m: np.ndarray, gate_m: np.ndarray, now_us: int) -> None:
        """Give every published track without an id one: a retired track's within its gate, else a new one.

        Args:
            keys: keys of the tracks published now.
            xy_m: (N, 2) their positions at ``now_us``.
            gate_m: (N,) their class's association gate (centre distance).
            now_us: the tracker's current stamp.
        """
        in_use = {self._ids[k] for k in keys if k in self._ids}
        self._retired = [r for r in self._retired if r.expires_us >= now_us and r.public_id not in in_use]
        new = [i for i, k in enumerate(keys) if k not in self._ids]
        if not new:
            return
        if self._retired:
            pred = np.array([r.xy_m + r.vxy_mps * ((now_us - r.stamp_us) * _US) for r in self._retired])
            d = np.linalg.norm(xy_m[new][:, None, :] - pred[None, :, :], axis=2)
            ok = d <= gate_m[new][:, None]
            rows, cols = linear_sum_assignment(np.where(ok, d, 1e9))
            taken: set[int] = set()
            for r, c in zip(rows, cols, strict=True):
                if ok[r, c]:
                    old = self._retired[c]
                    if self._ids.get(old.key) == old.public_id:
                        del self._ids[old.key]  # its own track, if published again, is a new object
                    self._ids[keys[new[r]]] = old.public_id
                    taken.add(int(c))
            self.inherited += len(taken)
            self._retired = [r for j, r in enumerate(self._retired) if j not in taken]
        for i in new:
            if keys[i] not in self._ids:
                self._ids[keys[i]] = self._next
                self._next += 1

    def forget_except(self, alive: set[TrackKey]) -> None:
        """Drop the ids of hypotheses that no longer exist (bounds memory over long runs)."""
        self._ids = {k: v for k, v in self._ids.items() if k in alive}
