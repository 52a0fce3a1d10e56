"""Gap acceptance arithmetic: when priority traffic reaches a conflict zone, how long the shuttle needs
to clear it, and the gap it must therefore be left (issue #20)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects, column
from lastmile.decision.give_way_config import GiveWayConfig
from lastmile.hdmap.give_way_zones import Approach

_X, _Y = column("x_m", TRACK_COLUMNS), column("y_m", TRACK_COLUMNS)
_VX, _VY = column("vx_mps", TRACK_COLUMNS), column("vy_mps", TRACK_COLUMNS)
_LEN, _CLS = column("length_m", TRACK_COLUMNS), column("class_id", TRACK_COLUMNS)
_GIVEN_WAY_TO = frozenset({ObjectClass.CAR, ObjectClass.CYCLIST, ObjectClass.UNKNOWN})
"""Road users that drive the lanes with priority; people and animals are the crosswalk and in-path
rules' (a radar track may stay unclassified: a moving one along the lane is taken as traffic)."""


@dataclass(frozen=True, slots=True)
class Arrival:
    """A road user on an approach: its track, when its front reaches the zone (0: in it now) and when
    its rear has left it (inf: standing in it)."""

    track_id: int
    time_s: float
    leave_s: float


def clearance_time_s(distance_m: float, speed_mps: float, accel_mps2: float, max_speed_mps: float) -> float:
    """Time to cover ``distance_m`` from ``speed_mps``, accelerating at ``accel_mps2`` up to
    ``max_speed_mps``. A start faster than that is taken at ``max_speed_mps`` all the way (it has to
    slow down for the turn; the time it gains braking is not counted, on the safe side)."""
    d, v0, a = max(distance_m, 0.0), max(speed_mps, 0.0), accel_mps2
    top = max_speed_mps
    if top <= 0.0:
        return math.inf
    if v0 >= top:
        return d / top
    t_up = (top - v0) / a
    d_up = (v0 + top) / 2.0 * t_up
    if d <= d_up:
        return (-v0 + math.sqrt(v0 * v0 + 2.0 * a * d)) / a
    return t_up + (d - d_up) / top


def arrival_on(tracks: TrackedObjects, approach: Approach, config: GiveWayConfig) -> list[Arrival]:
    """The road users on ``approach`` that still have the zone ahead or are in it, with their arrival.

    A road user's front reaches the zone after (zone start - its front) / its speed along the lane, and
    its rear leaves it after (zone end - its rear) / that speed; one inside the zone (any part of it
    between the zone's ends) arrives at 0, standing or not (standing, it never leaves); one standing
    (slower than ``moving_mps``) short of the zone does not arrive; one whose rear has left the zone is
    past it.
    """
    out: list[Arrival] = []
    line = approach.centerline
    # Only tracks within the approach's bounding box (grown by the lane's reach) are projected.
    reach = approach.half_width_m + config.lateral_margin_m
    lo, hi = line.xy_m.min(axis=0) - reach, line.xy_m.max(axis=0) + reach
    xy = tracks.table[:, [_X, _Y]]
    near = np.flatnonzero(np.all((xy >= lo) & (xy <= hi), axis=1))
    for k in near.tolist():
        row = tracks.table[k]
        if ObjectClass(int(row[_CLS])) not in _GIVEN_WAY_TO:
            continue
        x, y = float(row[_X]), float(row[_Y])
        f = line.project(x, y)
        if abs(f.d_m) > approach.half_width_m + config.lateral_margin_m:
            continue
        if f.s_m < 0.0 or f.s_m > approach.zone_end_m + float(row[_LEN]):
            continue  # beyond the approach's upstream end, or long past the zone
        heading = line.heading_at(f.s_m)
        vx, vy = float(row[_VX]), float(row[_VY])
        speed = math.hypot(vx, vy)
        along = vx * math.cos(heading) + vy * math.sin(heading)
        if speed >= config.moving_mps and along < config.heading_cos_min * speed:
            continue  # crossing the lane or coming the other way: not this approach's traffic
        half = float(row[_LEN]) / 2.0
        front, rear = f.s_m + half, f.s_m - half
        if rear > approach.zone_end_m:
            continue
        tid = int(tracks.ids[k])
        moving = along >= config.moving_mps
        leave = (approach.zone_end_m - rear) / along if moving else math.inf
        if front >= approach.zone_start_m:
            out.append(Arrival(tid, 0.0, leave))
        elif moving:
            out.append(Arrival(tid, (approach.zone_start_m - front) / along, leave))
    return out
