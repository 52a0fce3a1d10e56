"""The service's map as plain JSON for the dashboard to draw (no tiles: everything comes from the HD map)."""

from __future__ import annotations

from typing import Any

import numpy as np

from lastmile.fleet.scheduling import LoopRoute
from lastmile.hdmap.model import HDMap


def _pts(xy: np.ndarray, step: int = 1) -> list[list[float]]:
    return [[round(float(x), 1), round(float(y), 1)] for x, y in np.asarray(xy)[::step]]


def map_json(hdmap: HDMap, route: LoopRoute) -> dict[str, Any]:
    """Bounds, lanelet outlines (by subtype), the service loop, stops, crosswalks and buildings."""
    x0, y0, x1, y1 = hdmap.bounds_m
    for area in hdmap.areas:
        x0, y0 = min(x0, float(area.polygon[:, 0].min())), min(y0, float(area.polygon[:, 1].min()))
        x1, y1 = max(x1, float(area.polygon[:, 0].max())), max(y1, float(area.polygon[:, 1].max()))
    return {
        "name": hdmap.name,
        "bounds_m": [x0, y0, x1, y1],
        "lanelets": [
            {"id": lid, "subtype": ll.subtype, "polygon": _pts(ll.polygon())}
            for lid, ll in hdmap.lanelets.items()
        ],
        "loop": _pts(route.polyline.xy_m),
        "stops": [
            {"id": s.id, "name": s.name, "x_m": s.x_m, "y_m": s.y_m, "route_s_m": s.route_s_m}
            for s in route.stops.values()
        ],
        "crosswalks": [_pts(c.polygon) for c in hdmap.crosswalks],
        "areas": [{"subtype": a.subtype, "name": a.name, "polygon": _pts(a.polygon)} for a in hdmap.areas],
    }
