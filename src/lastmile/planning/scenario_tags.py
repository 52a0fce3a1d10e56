"""Snow Lion's scenario tags along the route: common road, parking lot, unprotected intersection.

Derived from the map, per s-layer record:

- **unprotected intersection**: the records of an uncontrolled junction (``intersection_type``
  UNCONTROLLED) or a driveway (``road_type`` DRIVEWAY, a junction without control such as a
  parking-lot entrance); all-way stops, signals and priority junctions are decision's;
- **parking lot**: records within ``parking_margin_m`` of a Lanelet2 area of subtype ``parking``, or on
  a lanelet the run configuration names (``[stack.path.behaviour] parking_lanelet_ids``);
- **common road**: everything else.
An unprotected intersection inside a parking lot is tagged as the intersection (its observation area
binds).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from lastmile.core.geometry import FloatArray
from lastmile.hdmap.layers import DRIVEWAY, UNCONTROLLED, SLayerDatabase


class ScenarioTag(IntEnum):
    """A route record's scenario."""

    COMMON_ROAD = 0
    PARKING_LOT = 1
    UNPROTECTED_INTERSECTION = 2


@dataclass(frozen=True, slots=True)
class TaggedStretch:
    """A contiguous stretch of one tag: route s from ``start_s_m`` to ``end_s_m`` (record starts)."""

    tag: ScenarioTag
    start_s_m: float
    end_s_m: float


def route_scenario_tags(
    layers: SLayerDatabase, parking_margin_m: float, parking_lanelet_ids: tuple[int, ...] = ()
) -> np.ndarray:
    """(N,) int8 :class:`ScenarioTag` per record of ``layers``."""
    tags = np.full(len(layers.s_m), ScenarioTag.COMMON_ROAD, dtype=np.int8)
    xy = layers.centerline.points_at(layers.s_m)
    parking = np.zeros(len(tags), dtype=bool)
    for area in layers.hdmap.areas:
        if area.subtype == "parking":
            parking |= polygon_distance_m(xy, np.asarray(area.polygon, dtype=float)) <= parking_margin_m
    if parking_lanelet_ids:
        parking |= np.isin(layers.lanelet_id, np.asarray(parking_lanelet_ids, dtype=np.int64))
    tags[parking] = ScenarioTag.PARKING_LOT
    junction = (layers.intersection_type == UNCONTROLLED) | (layers.road_type == DRIVEWAY)
    tags[junction] = ScenarioTag.UNPROTECTED_INTERSECTION
    return tags


def stretches(tags: np.ndarray, s_m: np.ndarray, step_m: float) -> tuple[TaggedStretch, ...]:
    """The runs of equal tags other than common road, as route-s stretches (end exclusive)."""
    out = []
    edges = np.flatnonzero(np.diff(tags.astype(np.int64))) + 1
    starts = np.r_[0, edges]
    ends = np.r_[edges, len(tags)]
    for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
        tag = ScenarioTag(int(tags[a]))
        if tag is not ScenarioTag.COMMON_ROAD:
            out.append(TaggedStretch(tag, float(s_m[a]), float(s_m[b - 1]) + step_m))
    return tuple(out)


def polygon_distance_m(points: FloatArray, polygon: FloatArray) -> FloatArray:
    """(N,) distance from each of ``points`` (N, 2) to the polygon (K, 2) outline; 0 inside it."""
    p = np.asarray(points, dtype=float)
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    ab = b - a  # (K, 2)
    ap = p[:, None, :] - a[None, :, :]  # (N, K, 2)
    t = np.clip((ap * ab).sum(axis=2) / np.maximum((ab * ab).sum(axis=1), 1e-12), 0.0, 1.0)
    nearest = a[None] + t[..., None] * ab[None]
    dist = np.hypot(*(p[:, None, :] - nearest).transpose(2, 0, 1)).min(axis=1)
    # Even-odd crossings: inside when a ray to +x crosses the outline an odd number of times.
    y0, y1 = a[:, 1][None], b[:, 1][None]
    py = p[:, 1:2]
    crosses = (y0 > py) != (y1 > py)
    x_at = a[:, 0][None] + (py - y0) * (b[:, 0] - a[:, 0])[None] / np.where(y1 == y0, 1.0, y1 - y0)
    inside = (crosses & (p[:, 0:1] < x_at)).sum(axis=1) % 2 == 1
    return np.where(inside, 0.0, dist)
