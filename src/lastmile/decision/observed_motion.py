"""How tracks have actually moved: velocities from their published positions over a window.

A tracker's constant-velocity estimate of a small standing object can point where the object is not
going: as the shuttle closes in, the part of a post or a sign the LiDAR sees shifts, and so does the
cluster's centre. In snow (seed 0, a_nom 1.0 m/s^2) a 0.6 x 0.2 m unclassified track beside a
crosswalk, 9 s old, read 0.67 m/s towards the road while its published positions had moved 0.5 m in
8.6 s (0.06 m/s); its constant-velocity path crossed the kerb, the crosswalk rule yielded to it at
5.5 m/s, and the yield was gone 0.3 s later (-2.12 m/s^3). What the positions did over a second or
more is the check on what the filter says they will do (``offroad_unknowns.yieldable_tracks``).

A trail keeps, per track id, the newest published position at least ``window_s`` old and every newer
one; the observed velocity is the displacement from that oldest sample over the time between. A
track published only now and then (the tracker keeps coasting ones unpublished) keeps its old sample
until a newer one is old enough, so the window is at least ``window_s``, never less.
"""

from __future__ import annotations

from collections.abc import Mapping

from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects

Trail = tuple[tuple[float, float, float], ...]
"""(t_s, x_m, y_m) samples of one track, oldest first."""

FORGET_S = 30.0
"""A trail whose track has not been published for this long is dropped (it bounds the memory; a
track that returns later starts a new trail, and is judged by its filter's velocity until the new
trail spans the window)."""
_AGE = TRACK_COLUMNS.index("age_s")
_AGE_TOLERANCE_S = 0.05
"""Samples older than the track's own age (less this) belong to an earlier track with the same id."""


def updated_trails(
    trails: Mapping[int, Trail], tracks: TrackedObjects, t_s: float, window_s: float
) -> dict[int, Trail]:
    """``trails`` with this cycle's positions of ``tracks`` (map frame) appended, each cut to the newest
    sample at least ``window_s`` old and the newer ones, and those unseen for ``FORGET_S`` dropped."""
    out = {tid: trail for tid, trail in trails.items() if t_s - trail[-1][0] <= FORGET_S}
    for tid, row in zip(tracks.ids.tolist(), tracks.table.tolist(), strict=True):
        born_s = t_s - row[_AGE] - _AGE_TOLERANCE_S
        trail = tuple(p for p in out.get(int(tid), ()) if p[0] >= born_s and p[0] < t_s)
        trail += ((t_s, row[0], row[1]),)
        first = 0
        for i, (ts, _, _) in enumerate(trail):
            if t_s - ts >= window_s - 1e-9:
                first = i
        out[int(tid)] = trail[first:]
    return out


def observed_velocities(
    trails: Mapping[int, Trail], tracks: TrackedObjects, window_s: float
) -> dict[int, tuple[float, float]]:
    """Track id -> (vx, vy) m/s, from its trail's first to its last sample, for the tracks in
    ``tracks`` whose trail (``updated_trails`` this cycle) spans at least ``window_s``."""
    out: dict[int, tuple[float, float]] = {}
    for tid in tracks.ids.tolist():
        trail = trails.get(int(tid))
        if trail is None:
            continue
        (t0, x0, y0), (t1, x1, y1) = trail[0], trail[-1]
        dt_s = t1 - t0
        if dt_s >= window_s - 1e-9:
            out[int(tid)] = ((x1 - x0) / dt_s, (y1 - y0) / dt_s)
    return out
