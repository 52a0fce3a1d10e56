"""Which tracks decision may yield to: not an unclassified object off the road that is not heading onto it;
which unclassified tracks are too new for the crosswalk rule to brake hard for, or a merge to wait for;
and which tracks have been seen as road users.

An object no sensor could classify, standing or moving beside the road and not towards it, is
scenery or a perception artefact (a kerb edge, a hedge, a return the ground removal missed): every
yield rule (in-path obstacles, cut-ins, crosswalks) would otherwise stop the shuttle for it once its
constant-velocity path ran alongside a crossing. A classified road user off the road (a pedestrian on
the sidewalk) is always kept: the crosswalk rule exists for exactly those.

"Off the road" is the footprint against the map's road surface (drivable and crosswalk lanelets);
"heading onto it" is the constant-velocity path of the footprint's centre entering it within the
horizon, at the filter's velocity and, once the track's positions span a second or more, at the
velocity they bear out (``observed_motion``: a standing post's cluster centre drifts as the shuttle
closes in, and the filter reads that as walking).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from matplotlib.path import Path as MplPath

from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.hdmap.model import HDMap

_X, _Y, _VX, _VY, _L, _W, _YAW, _CLS, _AGE = (
    TRACK_COLUMNS.index(c)
    for c in ("x_m", "y_m", "vx_mps", "vy_mps", "length_m", "width_m", "yaw_rad", "class_id", "age_s")
)
STEP_S = 0.5
"""Sampling of the constant-velocity path (a track at 6 m/s moves 3 m between samples; the road
surface is wider than that)."""


def on_road_surface(hdmap: HDMap, xy_m: np.ndarray) -> np.ndarray:
    """(N,) bool: which (N, 2) map points lie on a drivable lanelet or a crosswalk lanelet (the
    crossing's stretch of road; a crosswalk's marking drawn on over the sidewalk is not road)."""
    pts = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    on = hdmap.is_drivable(pts)
    rest = np.flatnonzero(~on)
    for lid, ll in hdmap.lanelets.items():
        if ll.subtype != "crosswalk" or len(rest) == 0:
            continue
        poly = hdmap.polygon_of(lid)
        lo, hi = poly.min(axis=0), poly.max(axis=0)
        near = rest[np.all((pts[rest] >= lo) & (pts[rest] <= hi), axis=1)]
        if len(near):
            on[near] = MplPath(poly).contains_points(pts[near])
            rest = np.flatnonzero(~on)
    return on


def yieldable_tracks(
    tracks: TrackedObjects,
    hdmap: HDMap,
    horizon_s: float,
    observed: Mapping[int, tuple[float, float]] | None = None,
) -> TrackedObjects:
    """``tracks`` without the unclassified ones whose footprint is off the road surface and whose
    constant-velocity path stays off it for ``horizon_s``, or, where ``observed`` has the track's
    velocity as its positions bear it out (``observed_motion``), whose path at that velocity does.

    Args:
        tracks: the tracker's output, map frame.
        hdmap: the map whose lanelets and crosswalks are the road surface.
        horizon_s: how far ahead the path is followed (>= 0).
        observed: track id -> (vx, vy) m/s its published positions moved at over the last second or
            more; a track without one is judged by its filter's velocity alone.
    """
    t = tracks.table
    unknown = np.flatnonzero(t[:, _CLS].astype(np.int64) == int(ObjectClass.UNKNOWN))
    if len(unknown) == 0:
        return tracks
    steps = np.arange(0.0, horizon_s + 1e-9, STEP_S)
    u = t[unknown]
    c, s = np.cos(u[:, _YAW]), np.sin(u[:, _YAW])
    hl, hw = u[:, _L] / 2.0, u[:, _W] / 2.0
    # Per track: its four corners, then its constant-velocity path (one map query for all tracks).
    corners = [
        np.column_stack([u[:, _X] + c * a - s * b, u[:, _Y] + s * a + c * b])
        for a, b in ((hl, hw), (hl, -hw), (-hl, hw), (-hl, -hw))
    ]
    seen = u[:, [_VX, _VY]].copy()
    for row, tid in enumerate(tracks.ids[unknown].tolist()):
        seen[row] = (observed or {}).get(int(tid), seen[row])
    path = [np.column_stack([u[:, _X] + u[:, _VX] * k, u[:, _Y] + u[:, _VY] * k]) for k in steps]
    borne_out = [np.column_stack([u[:, _X] + seen[:, 0] * k, u[:, _Y] + seen[:, 1] * k]) for k in steps]
    probes = np.stack(corners + path + borne_out, axis=1)  # (U, 4 + 2T, 2)
    on = on_road_surface(hdmap, probes.reshape(-1, 2)).reshape(len(unknown), -1)
    n = len(steps)
    # Heading onto the road: both the filter's velocity and the one its positions bear out take it there.
    heading_on = on[:, 4 : 4 + n].any(axis=1) & on[:, 4 + n :].any(axis=1)
    drop = np.zeros(len(t), dtype=bool)
    drop[unknown] = ~(on[:, :4].any(axis=1) | heading_on)
    if not drop.any():
        return tracks
    return TrackedObjects(stamp=tracks.stamp, ids=tracks.ids[~drop], table=t[~drop])


def kerbside_unknown_ids(tracks: TrackedObjects, hdmap: HDMap, standing_mps: float) -> frozenset[int]:
    """Ids of the unclassified tracks standing (speed below ``standing_mps``) with their centre off the
    road surface: at or beyond the road's edge, where a kerbside stop brings the body on purpose.

    Such a track may still overlap the road by part of its footprint (a 0.1 m LiDAR blob centred on
    the lane's edge), so ``yieldable_tracks`` keeps it; the in-path test then judges it against the
    body itself with a small margin rather than the lane's corridor margin
    (``stop_constraints.in_path_constraints``).
    """
    t = tracks.table
    unknown = np.flatnonzero(t[:, _CLS].astype(np.int64) == int(ObjectClass.UNKNOWN))
    if len(unknown) == 0:
        return frozenset()
    u = t[unknown]
    standing = np.hypot(u[:, _VX], u[:, _VY]) < standing_mps
    off = ~on_road_surface(hdmap, u[:, [_X, _Y]])
    return frozenset(int(i) for i in tracks.ids[unknown[standing & off]].tolist())


def unsettled_unknown_ids(
    tracks: TrackedObjects, settle_s: float, road_users: frozenset[int] = frozenset()
) -> frozenset[int]:
    """Ids of the unclassified tracks younger than ``settle_s``, but for those in ``road_users``: too
    new for the crosswalk rule to brake harder than comfortably for them (``crosswalk_yield``), for a
    merge to wait for them, or to be taken for a lead beside the body (``in_path_constraints``).

    Precipitation echoes near the window form such tracks for a few sweeps; a stop point that appears
    for them a few metres ahead and is gone a cycle later is braked for at the urgent rate. A track
    already classified as a road user (``road_user_ids``) is not one, whatever its class now.
    """
    t = tracks.table
    young = (t[:, _CLS].astype(np.int64) == int(ObjectClass.UNKNOWN)) & (t[:, _AGE] < settle_s)
    return frozenset(int(i) for i in tracks.ids[young].tolist()) - road_users


def road_user_ids(tracks: TrackedObjects, before: frozenset[int]) -> frozenset[int]:
    """Ids of the tracks classified as a road user (any class but unknown) now, or in an earlier cycle
    while tracked since (``before``: the previous cycle's answer).

    The class a track carries can flicker: a person 0.7 s tracked, yielded to at a crosswalk from 13 m
    at 5.5 m/s, read as unclassified for a few sweeps (clear, seed 4, a_nom 1.0); taken for a new
    unclassified track, the yield was dropped as no longer comfortable, and 0.3 s later, settled, it
    returned as an urgent stop (-2.28 m/s^2, +18 m/s^3 at its end). A track seen as a road user stays
    one for as long as it is tracked.
    """
    t = tracks.table
    classified = t[:, _CLS].astype(np.int64) != int(ObjectClass.UNKNOWN)
    tracked = frozenset(int(i) for i in tracks.ids.tolist())
    return frozenset(int(i) for i in tracks.ids[classified].tolist()) | (before & tracked)
