"""Tracked objects expressed along the route (s ahead, d left), the frame every decision is made in."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.polyline import Polyline

_X, _Y, _VX, _VY, _L, _W, _YAW, _CLS = (
    TRACK_COLUMNS.index(c)
    for c in ("x_m", "y_m", "vx_mps", "vy_mps", "length_m", "width_m", "yaw_rad", "class_id")
)


@dataclass(frozen=True, slots=True)
class RouteObstacle:
    """One track in route coordinates; ``ds_m`` is centre-to-ego-front distance along the route."""

    track_id: int
    cls: ObjectClass
    x_m: float
    y_m: float
    s_m: float
    ds_m: float
    d_m: float
    v_s_mps: float
    v_d_mps: float
    length_m: float
    width_m: float

    @property
    def speed_mps(self) -> float:
        return math.hypot(self.v_s_mps, self.v_d_mps)


def route_obstacles(
    tracks: TrackedObjects,
    route: Polyline,
    ego_s_m: float,
    ego_front_offset_m: float,
    horizon_m: float = 80.0,
) -> list[RouteObstacle]:
    """Tracks within ``horizon_m`` of the ego projected onto the (closed) route near the ego."""
    out: list[RouteObstacle] = []
    ex, ey, _ = route.point_at(ego_s_m)
    for tid, row in zip(tracks.ids.tolist(), tracks.table.tolist(), strict=True):
        x, y = row[_X], row[_Y]
        dist = math.hypot(x - ex, y - ey)
        if dist > horizon_m:
            continue
        f = route.project(x, y, hint_s_m=ego_s_m + dist, window_m=dist + 10.0)
        heading = route.heading_at(f.s_m)
        c, s = math.cos(heading), math.sin(heading)
        ds = route.ds_m(ego_s_m, f.s_m)
        out.append(
            RouteObstacle(
                track_id=int(tid),
                cls=ObjectClass(int(row[_CLS])),
                x_m=x,
                y_m=y,
                s_m=f.s_m,
                ds_m=ds - ego_front_offset_m,
                d_m=f.d_m,
                v_s_mps=row[_VX] * c + row[_VY] * s,
                v_d_mps=-row[_VX] * s + row[_VY] * c,
                length_m=row[_L],
                width_m=row[_W],
            )
        )
    return out
