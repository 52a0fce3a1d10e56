"""Fills WATonoBus's s-layer database from the map along a route (Fig. 7 of the WATonoBus paper).

Every layer is computed once here, so the stack's per-tick look-ups are array indexing.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from lastmile.core.errors import MapError
from lastmile.core.polyline import Polyline
from lastmile.hdmap.lane_change import KeepClear
from lastmile.hdmap.layers import (
    ALL_WAY_STOP,
    BUS_BAY,
    CROSSWALK,
    DRIVEWAY,
    INTERSECTION,
    LANDMARK_RADIUS_M,
    PRIORITY,
    SIGNALISED,
    UNCONTROLLED,
    RouteCrosswalk,
    RouteStop,
    RouteStopLine,
)
from lastmile.hdmap.model import HDMap, LaneletInfo
from lastmile.hdmap.routing import lanelet_starts_m, route_pieces, route_polyline

if TYPE_CHECKING:
    from lastmile.hdmap.layers import SLayerDatabase

TURNS = ("left", "right")  # a turn_direction that makes a one-sided branch or merge a junction
CROSSWALK_REACH_M = 8.0  # a crosswalk belongs to the route when its centre is this close to the lane


def build_layers(
    cls: type[SLayerDatabase],
    hdmap: HDMap,
    lanelet_ids: tuple[int, ...],
    step_m: float,
    closed: bool,
    unmapped_speed_limit_mps: float | None = None,
    keep_clear: tuple[KeepClear, ...] = (),
    steerable: bool = False,
) -> SLayerDatabase:
    if not (math.isfinite(step_m) and step_m > 0):
        raise MapError(f"SLayerDatabase.build step_m: expected a positive step, got {step_m}")
    limits = _speed_limits(hdmap, lanelet_ids, unmapped_speed_limit_mps)
    centre = route_polyline(
        hdmap,
        lanelet_ids,
        closed=closed,
        unmapped_speed_limit_mps=unmapped_speed_limit_mps,
        keep_clear=keep_clear,
        steerable=steerable,
    )
    starts = lanelet_starts_m(hdmap, lanelet_ids)
    # Lanelet lengths sum to the joined line's length up to rounding; scale so s maps exactly.
    starts *= centre.length_m / starts[-1]
    n = int(centre.length_m // step_m) + (0 if closed else 1)
    s = np.arange(n, dtype=float) * step_m
    which = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(lanelet_ids) - 1)
    lane_of = np.asarray(lanelet_ids, dtype=np.int64)[which]
    pts = centre.points_at(s)
    limit, left, right, curb = (np.empty(n) for _ in range(4))
    # A stop without a bay (its "bay" is the lane itself) adds no curb: the lane's edge may be paint.
    bays = {
        st.lane_lanelet_id: hdmap.lanelets[st.bay_lanelet_id]
        for st in hdmap.stops
        if st.bay_lanelet_id != st.lane_lanelet_id
    }
    curb_side = _curb_lanelets(hdmap, lanelet_ids)
    for i, (lid, (x, y)) in enumerate(zip(lane_of.tolist(), pts.tolist(), strict=True)):
        info = hdmap.lanelets[lid]
        limit[i] = limits[lid]
        left[i] = abs(info.left.project(x, y).d_m)
        right[i] = -abs(info.right.project(x, y).d_m)
        if info.right_is_curb:
            curb[i] = right[i]
        elif lid in bays:
            curb[i] = -abs(bays[lid].right.project(x, y).d_m)
        elif lid in curb_side:
            curb[i] = -abs(curb_side[lid].right.project(x, y).d_m)
        else:
            curb[i] = math.nan  # an opening (junction, driveway): no curb to stop against
    road, junction = _road_types(hdmap, lanelet_ids, lane_of, n)
    stops = _route_stops(hdmap, centre, lanelet_ids)
    crosswalks = route_crosswalks(hdmap, centre)
    for rc in crosswalks:
        road[(s >= rc.s_start_m) & (s <= rc.s_end_m) & (road == 0)] = CROSSWALK
    for rs in stops:
        road[(s >= rs.s_start_m) & (s <= rs.s_end_m) & (road == 0)] = BUS_BAY
    lm_start, lm_index = _landmarks_near(hdmap, pts)
    return cls(
        hdmap=hdmap,
        centerline=centre,
        step_m=step_m,
        s_m=s,
        speed_limit_mps=limit,
        lane_left_d_m=left,
        lane_right_d_m=right,
        curb_right_d_m=curb,
        road_type=road,
        intersection_type=junction,
        lanelet_id=lane_of,
        landmark_start=lm_start,
        landmark_index=lm_index,
        stops=stops,
        crosswalks=crosswalks,
        stop_lines=_route_stop_lines(hdmap, lanelet_ids, starts),
    )


def _speed_limits(hdmap: HDMap, lanelet_ids: tuple[int, ...], unmapped_mps: float | None) -> dict[int, float]:
    """Each route lanelet's limit: the mapped one, else ``unmapped_mps``; never a silent default."""
    if unmapped_mps is not None and not (math.isfinite(unmapped_mps) and unmapped_mps > 0):
        raise MapError(f"unmapped speed limit: expected a positive number of m/s, got {unmapped_mps}")
    out: dict[int, float] = {}
    missing: list[int] = []
    for lid in dict.fromkeys(lanelet_ids):
        mapped = hdmap.lanelets[lid].speed_limit_mps
        if math.isfinite(mapped):
            out[lid] = mapped
        elif unmapped_mps is not None:
            out[lid] = unmapped_mps
        else:
            missing.append(lid)
    if missing:
        raise MapError(
            f"map {hdmap.name!r}: expected a speed limit on every route lanelet (a speed_limit tag, or the "
            f"route file's unmapped_speed_limit_kph), got none on {len(missing)} lanelets ({missing[:5]})"
        )
    return out


MAX_LANES_TO_CURB = 4  # lanes between the route's lane and a curb that still counts as the road's edge


def _curb_lanelets(hdmap: HDMap, lanelet_ids: tuple[int, ...]) -> dict[int, LaneletInfo]:
    """For route lanelets whose right bound is a lane line: the lanelet beside them (same direction,
    sharing that line as its left bound, up to MAX_LANES_TO_CURB lanes over) whose right bound is a curb.
    """
    by_left_bound: dict[int, int] = {}
    for lid, info in hdmap.lanelets.items():
        if info.left_bound_id and info.subtype in ("road", "bus_lane", "highway"):
            by_left_bound.setdefault(info.left_bound_id, lid)
    out: dict[int, LaneletInfo] = {}
    for lid in dict.fromkeys(lanelet_ids):
        info = hdmap.lanelets[lid]
        for _ in range(MAX_LANES_TO_CURB):
            if info.right_is_curb or not info.right_bound_id:
                break
            nxt = by_left_bound.get(info.right_bound_id)
            # The same bound id seen from the other direction is the lane across the road, not beside it.
            if nxt is None or (nxt < 0) != (lid < 0) or nxt == lid:
                break
            info = hdmap.lanelets[nxt]
        if info.right_is_curb and info.id != lid:
            out[lid] = info
    return out


def _road_types(
    hdmap: HDMap, lanelet_ids: tuple[int, ...], lane_of: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Junction records: inside an all-way stop, or past a signal's or a right-of-way rule's entry
    where the route branches, merges or crosses another lane's path (intersection); at an uncontrolled
    branch-and-merge or crossing (driveway)."""
    predecessors: dict[int, int] = {}
    for succ in hdmap.successor_ids.values():
        for lid in succ:
            predecessors[lid] = predecessors.get(lid, 0) + 1
    inside_stop = {
        s for aws in hdmap.all_way_stops for e in aws.entry_lanelet_ids for s in hdmap.successors(e)
    }
    signal_entries = {sl.lanelet_id for sl in hdmap.stop_lines if sl.signal_id is not None}
    road = np.zeros(n, dtype=np.int8)
    junction = np.zeros(n, dtype=np.int8)
    for k, lid in enumerate(lanelet_ids):
        prev = lanelet_ids[k - 1] if k > 0 else None
        nxt = lanelet_ids[k + 1] if k + 1 < len(lanelet_ids) else None
        # Only successor links make a junction; a lane change beside a lanelet is no branch.
        branches = (
            prev is not None and lid in hdmap.successor_ids.get(prev, ()) and len(hdmap.successors(prev)) > 1
        )
        merges = nxt is not None and nxt in hdmap.successor_ids.get(lid, ()) and predecessors.get(nxt, 0) > 1
        crosses = bool(hdmap.conflict_ids.get(lid))  # another lane's path overlaps this one
        at_junction = branches or merges or crosses
        mask = lane_of == lid
        if lid in inside_stop:
            road[mask], junction[mask] = INTERSECTION, ALL_WAY_STOP
        elif at_junction and prev in signal_entries:
            road[mask], junction[mask] = INTERSECTION, SIGNALISED
        elif at_junction and prev in hdmap.priority_lanelet_ids:
            road[mask], junction[mask] = INTERSECTION, PRIORITY
        elif (branches and merges) or crosses or (at_junction and hdmap.lanelets[lid].turn in TURNS):
            road[mask], junction[mask] = DRIVEWAY, UNCONTROLLED
    return road, junction


def _route_stops(hdmap: HDMap, centre: Polyline, lanelet_ids: tuple[int, ...]) -> tuple[RouteStop, ...]:
    out = []
    for stop in hdmap.stops:
        if stop.lane_lanelet_id not in lanelet_ids:
            continue
        proj = [centre.project(float(x), float(y)) for x, y in stop.curb.xy_m]
        out.append(
            RouteStop(
                stop=stop,
                s_start_m=proj[0].s_m,
                s_end_m=proj[-1].s_m,
                curb_d_m=float(np.mean([p.d_m for p in proj])),
            )
        )
    return tuple(sorted(out, key=lambda r: r.s_start_m))


def route_crosswalks(hdmap: HDMap, centre: Polyline) -> tuple[RouteCrosswalk, ...]:
    """The mapped crosswalks ``centre`` crosses (their centre within CROSSWALK_REACH_M), in s order."""
    out = []
    for cw in hdmap.crosswalks:
        poly = np.asarray(cw.polygon, dtype=float)
        mid = centre.project(*map(float, poly.mean(axis=0)))
        if abs(mid.d_m) > CROSSWALK_REACH_M:
            continue
        ss = [centre.project(float(x), float(y), hint_s_m=mid.s_m, window_m=30.0).s_m for x, y in poly]
        out.append(RouteCrosswalk(crosswalk=cw, s_start_m=min(ss), s_end_m=max(ss)))
    return tuple(sorted(out, key=lambda r: r.s_start_m))


def _route_stop_lines(
    hdmap: HDMap, lanelet_ids: tuple[int, ...], starts: np.ndarray
) -> tuple[RouteStopLine, ...]:
    """A stop line sits at the end of its lanelet, so its s is where the next lanelet begins (a lanelet
    the route leaves by a lane change never reaches its line)."""
    pieces = route_pieces(hdmap, lanelet_ids)
    out = []
    for line in hdmap.stop_lines:
        for k, lid in enumerate(lanelet_ids):
            if lid == line.lanelet_id and pieces[k].s1_m == math.inf:
                out.append(
                    RouteStopLine(
                        stop_line=line, s_m=float(starts[k + 1]), all_way_stop_id=line.all_way_stop_id
                    )
                )
    return tuple(sorted(out, key=lambda r: r.s_m))


def _landmarks_near(hdmap: HDMap, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = len(pts)
    if not hdmap.landmarks:
        return np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    where = np.array([np.asarray(lm.xy, dtype=float).mean(axis=0) for lm in hdmap.landmarks])
    tree = cKDTree(where)
    hits = tree.query_ball_point(pts, r=LANDMARK_RADIUS_M)
    index: list[int] = []
    start = np.zeros(n + 1, dtype=np.int64)
    for i, found in enumerate(hits):
        order = sorted(found, key=lambda j: float(np.hypot(*(where[j] - pts[i]))))
        index.extend(order)
        start[i + 1] = len(index)
    return start, np.asarray(index, dtype=np.int64)
