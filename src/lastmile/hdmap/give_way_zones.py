"""Where a route yields at a junction: the conflict zones between its lanelet through the junction and
the lanelets with priority, and the ways priority traffic comes to each (issue #20).

Two kinds of line make the route yield:

- a **give-way line**: the stop line of a Lanelet2 ``right_of_way`` rule the route's lanelet yields
  under (``StopLine.right_of_way_id``); the lanelets with priority are the rule's ``rightOfWay``
  lanelets;
- a **two-way stop**: a stop sign's line outside an all-way stop or a signal (``StopLine.stop_sign_id``);
  the lanelets with priority are those of the junction whose approach has no stop line of any kind
  (the through road).

Of those, only the lanelets Lanelet2 finds in conflict with the route's lanelet (``HDMap.conflict_ids``:
their areas overlap, crossing or merging) matter. The **conflict zone** of one such pair is where the two
lanelets' areas overlap; it is kept as the stretch of the route it covers (from the line) and the stretch
of each approach to it (the priority lanelet and its predecessors, up to ``lookback_m`` upstream). The
overlap is found by sampling both lanelets' areas (points between their bounds), so curved lanelets and
merges need no polygon clipping.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from lastmile.core.geometry import FloatArray, PreparedPolygon
from lastmile.core.polyline import Polyline
from lastmile.hdmap.model import HDMap, LaneletInfo, StopLine

SAMPLE_STEP_M = 0.25
"""Spacing of the sample points along a lanelet (the overlap's ends are found to about this)."""
LATERAL_SAMPLES = 9
"""Sample points across a lanelet at each station, between 2 % and 98 % of its width: lanelets side by
side share a bound, and a point on it is in neither's conflict."""
MAX_APPROACHES = 8
"""Upstream branches kept per priority lanelet (a junction upstream splits the approach)."""
LINE_END_REACH_M = 1.5
"""A lanelet whose centre line ends this close to a stop line ends at it (its approach is controlled)."""
ROUTE_MATCH_M = 1.5
"""The route's lanelet through a junction is the candidate whose centre line keeps on average within
this of the route (the route rounds corners the shuttle cannot steer, so it is not the centre line)."""


class YieldKind(Enum):
    """Why the route yields at a line."""

    GIVE_WAY = "give_way"
    """A ``right_of_way`` rule's line: no stop is owed, the priority traffic is."""
    STOP_SIGN = "stop_sign"
    """A two-way stop: a full stop, then the priority traffic."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Approach:
    """One way priority traffic comes to a conflict zone.

    Attributes:
        lanelet_ids: upstream first, ending with the priority lanelet.
        centerline: their centre lines joined.
        half_width_m: half the narrowest lane's width: farther off the centre line, not on it.
        zone_start_m, zone_end_m: where the conflict zone begins and ends along ``centerline``.
    """

    lanelet_ids: tuple[int, ...]
    centerline: Polyline
    half_width_m: float
    zone_start_m: float
    zone_end_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class ConflictZone:
    """Where the route's lanelet through the junction overlaps one lanelet with priority.

    Attributes:
        priority_lanelet_id: the lanelet with priority.
        start_after_line_m, end_after_line_m: the zone's stretch of the route, as route distances from the
            line (the shuttle's front is in the zone from the first; its rear has left it at the second).
        approaches: the ways traffic on the priority lanelet comes to it.
    """

    priority_lanelet_id: int
    start_after_line_m: float
    end_after_line_m: float
    approaches: tuple[Approach, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class YieldJunction:
    """A line on the route where the shuttle yields, and what it yields to.

    Attributes:
        stop_line: the line (a give-way line or a two-way stop's).
        line_s_m: its route s.
        kind: give way or stop sign.
        name: the rule's name (a give-way line), else "".
        route_lanelet_id: the route's lanelet through the junction, after the line.
        turn: the route's movement there: "left", "right" or "straight".
        zones: the conflict zones with the lanelets that have priority (may be empty).
    """

    stop_line: StopLine
    line_s_m: float
    kind: YieldKind
    name: str
    route_lanelet_id: int
    turn: str
    zones: tuple[ConflictZone, ...]


def yield_kind(line: StopLine) -> YieldKind | None:
    """Whether the route yields at ``line`` (a give-way line or a two-way stop), else None."""
    if line.all_way_stop_id is not None or line.signal_id is not None:
        return None  # their own rules (arrival order, the signal) decide who goes
    if line.stop_sign_id is not None:
        return YieldKind.STOP_SIGN
    if line.right_of_way_id is not None:
        return YieldKind.GIVE_WAY
    return None


def yield_junctions(
    hdmap: HDMap, route: Polyline, lines: Sequence[tuple[StopLine, float]], lookback_m: float
) -> tuple[YieldJunction, ...]:
    """The yield junctions of the route at ``lines`` ((line, its route s); others are left out).

    Args:
        lookback_m: how far upstream of a conflict zone its approaches reach.
    """
    preds = _predecessors(hdmap)
    out = []
    for line, line_s in lines:
        kind = yield_kind(line)
        if kind is None:
            continue
        lane = _route_lanelet(hdmap, route, line, line_s)
        if lane is None:
            continue
        name, priority = _priority_lanelets(hdmap, line, kind, lane, preds)
        zones = tuple(
            zone
            for pid in priority
            if (zone := _zone(hdmap, route, line_s, lane, pid, preds, lookback_m)) is not None
        )
        out.append(
            YieldJunction(
                stop_line=line,
                line_s_m=line_s,
                kind=kind,
                name=name,
                route_lanelet_id=lane,
                turn=movement(hdmap.lanelets[lane]),
                zones=zones,
            )
        )
    return tuple(out)


def movement(lanelet: LaneletInfo) -> str:
    """ "left", "right" or "straight": the lanelet's ``turn_direction`` tag, else its heading change
    (more than 45 degrees either way is a turn)."""
    if lanelet.turn in ("left", "right", "straight"):
        return lanelet.turn
    c = lanelet.centerline
    bend = math.remainder(c.heading_at(c.length_m) - c.heading_at(0.0), 2 * math.pi)
    if abs(bend) <= math.radians(45.0):
        return "straight"
    return "left" if bend > 0 else "right"


def _predecessors(hdmap: HDMap) -> dict[int, tuple[int, ...]]:
    pred: dict[int, list[int]] = {}
    for lid, succ in sorted(hdmap.successor_ids.items()):
        for s in succ:
            pred.setdefault(s, []).append(lid)
    return {k: tuple(v) for k, v in pred.items()}


def _ends_at(lanelet: LaneletInfo, line: StopLine) -> bool:
    """Whether the lanelet's centre line ends at the stop line."""
    x, y = lanelet.centerline.xy_m[-1]
    a, b = np.asarray(line.line, dtype=float)
    ab = b - a
    t = float(np.clip(((x - a[0]) * ab[0] + (y - a[1]) * ab[1]) / max(float(ab @ ab), 1e-12), 0.0, 1.0))
    return math.hypot(x - a[0] - t * ab[0], y - a[1] - t * ab[1]) < LINE_END_REACH_M


def _route_lanelet(hdmap: HDMap, route: Polyline, line: StopLine, line_s_m: float) -> int | None:
    """The lanelet after the line that the route follows: among the successors of the lanelets ending
    at the line, the one whose centre line the route keeps closest to."""
    enders = [lid for lid, ll in hdmap.lanelets.items() if _ends_at(ll, line)]
    candidates = sorted({s for lid in enders for s in hdmap.successors(lid)})
    best: tuple[float, int] | None = None
    for lid in candidates:
        c = hdmap.lanelets[lid].centerline
        pts = c.points_at(np.linspace(0.0, c.length_m, 9))
        d = [abs(route.project(float(x), float(y), hint_s_m=line_s_m, window_m=60.0).d_m) for x, y in pts]
        mean = float(np.mean(d))
        if mean < ROUTE_MATCH_M and (best is None or mean < best[0]):
            best = (mean, lid)
    return best[1] if best is not None else None


def _priority_lanelets(
    hdmap: HDMap, line: StopLine, kind: YieldKind, lane: int, preds: dict[int, tuple[int, ...]]
) -> tuple[str, tuple[int, ...]]:
    """(the rule's name, the lanelets with priority over ``lane`` that conflict with it)."""
    conflicting = hdmap.conflict_ids.get(lane, ())
    if kind is YieldKind.GIVE_WAY:
        rule = next(r for r in hdmap.right_of_way_rules if r.id == line.right_of_way_id)
        return rule.name, tuple(sorted(set(conflicting) & set(rule.priority_lanelet_ids)))
    # A two-way stop: priority is with the lanelets whose approach no line controls.
    controlled = [sl for sl in hdmap.stop_lines]
    free = tuple(
        sorted(
            pid
            for pid in conflicting
            if not any(_ends_at(hdmap.lanelets[q], sl) for q in preds.get(pid, ()) for sl in controlled)
        )
    )
    return "", free


def _area_samples(lanelet: LaneletInfo) -> FloatArray:
    """(N, 2) points spread over the lanelet's area, between its bounds."""
    left, right = lanelet.left, lanelet.right
    n = max(2, math.ceil(max(left.length_m, right.length_m) / SAMPLE_STEP_M) + 1)
    f = np.linspace(0.0, 1.0, n)
    lp = left.points_at(f * left.length_m)
    rp = right.points_at(f * right.length_m)
    t = np.linspace(0.02, 0.98, LATERAL_SAMPLES)[None, :, None]
    return ((1.0 - t) * lp[:, None, :] + t * rp[:, None, :]).reshape(-1, 2)


def _inside(points: FloatArray, lanelet: LaneletInfo) -> FloatArray:
    poly = PreparedPolygon(lanelet.polygon())
    keep = [poly.contains(float(x), float(y)) for x, y in points]
    return points[np.asarray(keep, dtype=bool)] if len(points) else points


def _zone(
    hdmap: HDMap,
    route: Polyline,
    line_s_m: float,
    lane: int,
    priority: int,
    preds: dict[int, tuple[int, ...]],
    lookback_m: float,
) -> ConflictZone | None:
    """The conflict zone of the route's lanelet with one priority lanelet (None: the areas only touch)."""
    mine, theirs = hdmap.lanelets[lane], hdmap.lanelets[priority]
    on_route = _inside(_area_samples(mine), theirs)
    on_priority = _inside(_area_samples(theirs), mine)
    if len(on_route) == 0 or len(on_priority) == 0:
        return None
    ahead = [
        route.ds_m(line_s_m, route.project(float(x), float(y), hint_s_m=line_s_m, window_m=60.0).s_m)
        for x, y in on_route
    ]
    approaches = []
    for chain in _upstream_chains(hdmap, priority, preds, lookback_m):
        centre = Polyline(np.vstack([hdmap.lanelets[lid].centerline.xy_m for lid in chain]))
        along = [centre.project(float(x), float(y)).s_m for x, y in on_priority]
        approaches.append(
            Approach(
                lanelet_ids=chain,
                centerline=centre,
                half_width_m=min(_width_m(hdmap.lanelets[lid]) for lid in chain) / 2.0,
                zone_start_m=float(min(along)),
                zone_end_m=float(max(along)),
            )
        )
    return ConflictZone(
        priority_lanelet_id=priority,
        start_after_line_m=float(min(ahead)),
        end_after_line_m=float(max(ahead)),
        approaches=tuple(approaches),
    )


def _upstream_chains(
    hdmap: HDMap, priority: int, preds: dict[int, tuple[int, ...]], lookback_m: float
) -> list[tuple[int, ...]]:
    """Chains of lanelets ending with ``priority``, each reaching ``lookback_m`` upstream of its start
    (or the map's edge), at most ``MAX_APPROACHES`` of them."""
    done: list[tuple[int, ...]] = []
    open_: list[tuple[tuple[int, ...], float]] = [((priority,), 0.0)]
    while open_ and len(done) + len(open_) <= MAX_APPROACHES:
        chain, reach = open_.pop(0)
        ups = [p for p in preds.get(chain[0], ()) if p not in chain] if reach < lookback_m else []
        if not ups:
            done.append(chain)
            continue
        for p in ups:
            open_.append(((p, *chain), reach + hdmap.lanelets[p].centerline.length_m))
    done.extend(chain for chain, _ in open_)
    return done[:MAX_APPROACHES]


def _width_m(lanelet: LaneletInfo) -> float:
    c = lanelet.centerline
    x, y, _ = c.point_at(c.length_m / 2.0)
    return abs(lanelet.left.project(x, y).d_m) + abs(lanelet.right.project(x, y).d_m)
