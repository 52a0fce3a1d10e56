"""A shuttle service on a user's map: ``load_route(route.toml) -> ServiceRoute``.

The route file names the map and its projection and the stops; each stop is snapped to the nearest
drivable lanelet (the distance is reported, over ``MAX_SNAP_M`` is an error), and A* over the lanelet
graph (aUToronto 7.1.2, Snow Lion's A* routing) joins consecutive stops into one closed service path.
As in aUToronto's global planner, two stops on the same lanelet need no search when the second lies
ahead of the first, and a path round the network back to that lanelet when it lies behind.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.core.errors import ConfigError, MapError, RoutingError
from lastmile.core.geometry import point_in_polygon
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.curb_fit import CURB_GAP_TARGET_M, rest_door_gap_m
from lastmile.hdmap.lane_change import KeepClear, RoadOutline
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map, load_projected_map
from lastmile.hdmap.model import DRIVABLE_SUBTYPES, BusStop, HDMap, LaneletInfo
from lastmile.hdmap.route_file import (
    MAX_SNAP_M,
    RouteSpec,
    ServicePattern,
    StopSource,
    heading_rad,
    read_route_file,
)
from lastmile.hdmap.routing import campus_shuttle_loop, lanelet_starts_m, route, route_pieces, route_polyline
from lastmile.hdmap.waypoints import read_waypoints

GAP_HEADING_TOLERANCE_RAD = math.radians(45.0)
"""A bridged gap joins lanes heading the same way: more than this apart is a turn, not a gap."""
PLATFORM_MARGIN_M = 5.0  # between a platform and the loop's start, where a bridged gap bends the line
SAME_PLACE_M = 0.5  # a stop this little ahead of the previous one on its lanelet is the same place
KERBSIDE_APPROACH_M = 32.0
"""Route length a pull-over needs before its spot (the decision layer's ``transition_m``): a kerbside
stop's edge is the lane's narrowest over this approach and the platform."""
ROAD_EDGE_STEP_M = 0.1  # resolution of the road's edge beside a kerbside stop's approach
DOOR_SPREAD_M = 0.5
SETTLE_RUN_M = 8.0
"""The straight run along the kerb the planner ends its pull-over with before the spot
(``planning.local_path.LocalPathConfig.settle_m``): a bend towards the kerb there off-tracks the rear
axle onto it (K-Block on the BITS loop, on the exit of the S-bend's fillet: the door ended 0.06 m over
the kerb line and the stop was missed with five waiting)."""
"""A kerbside place must keep the door gap for a door this far either side of where it is aimed (the
pull-over's longitudinal stopping error): on a mapped polygon the gap can change sharply at a vertex."""
MOVE_STEP_M = 0.5  # places tried along the lane when a kerbside stop is moved off a bend
INTERSECTION_REACH_M = 30.0
"""Branches and merges this close along the route are one place (a junction box of a few lanes each
way, or a roundabout's arms)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Snap:
    """A position put on a lanelet.

    Attributes:
        lanelet_id: the directed lanelet (negative: a two-way lanelet driven against its drawing).
        lanelet_s_m: along that lanelet's centre line.
        offset_m: signed distance from its centre line (left positive).
        distance_m: from the position to the lanelet's outline (0 inside).
    """

    lanelet_id: int
    lanelet_s_m: float
    offset_m: float
    distance_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class ServiceStop:
    """A stop of the service, in service order.

    Attributes:
        name: unique within the route, and the id of its ``BusStop`` in ``ServiceRoute.hdmap`` (the
            return side of an out-and-back stop is "NAME (return)").
        x_m, y_m: where the route file (or the map) put it, map frame.
        snap: its lanelet, and how far it was from it.
        route_s_m: along ``ServiceRoute.polyline``; a stop whose platform would straddle the loop's
            start (s = 0) is moved along the lane until it does not (at most half a platform); a
            kerbside stop where the door cannot come within ``RouteSpec.max_door_gap_m`` of the kerb
            (a bend the straight body cannot lie along) is moved to the nearest place where it can,
            within ``RouteSpec.max_stop_move_m``.
        moved_m: how far (route s, signed) the stop was moved from where it snapped.
        door_gap_m: the door's gap to the kerb a pull-over at the platform's middle is expected to
            leave (``curb_fit.rest_door_gap_m``), where the stop ends up; None for a mapped bay.
        door_gap_given_m: the same where the stop was given (differs from ``door_gap_m`` if moved).
        source: "file", "bay" (a mapped ``lastmile:bus_stop`` bay), "lastmile:bus_stop" (a tagged
            node) or "autoware:bus_stop_area".
    """

    name: str
    x_m: float
    y_m: float
    snap: Snap
    route_s_m: float
    source: str
    moved_m: float = 0.0
    door_gap_m: float | None = None
    door_gap_given_m: float | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class RouteJunction:
    """Where other traffic leaves (``branch``) or joins (``merge``) the service path, at route s."""

    s_m: float
    kind: str
    lanelet_id: int


@dataclass(frozen=True, slots=True, kw_only=True)
class ServiceRoute:
    """A service on a map: what the runner needs to build the world and the stack.

    Attributes:
        hdmap: the map, its ``stops`` replaced by this service's stops (mapped bays kept as they are;
            the others a kerbside ``BusStop`` whose bay is the lane itself and whose curb is the lane's
            right edge over ``platform_length_m``), a connector lanelet over each bridged gap.
        lanelet_ids: the closed service path (the last lanelet is followed by the first).
        polyline: its centre line, closed.
        stops: in service order.
        unmapped_speed_limit_mps: the route file's limit for lanelets whose map states none.
        bridged_gaps: (from lanelet, to lanelet, gap m) bridged by ``connect_gaps_m``, each through a
            new connector lanelet.
        junctions: branches and merges along the path, in route s.
        keep_clear: the stops' platforms, which the path's lane changes keep out of where they can
            (the same for ``polyline`` and ``layers()``).
    """

    name: str
    spec: RouteSpec | None
    hdmap: HDMap
    lanelet_ids: tuple[int, ...]
    polyline: Polyline
    stops: tuple[ServiceStop, ...]
    unmapped_speed_limit_mps: float | None
    bridged_gaps: tuple[tuple[int, int, float], ...] = ()
    junctions: tuple[RouteJunction, ...] = ()
    keep_clear: tuple[KeepClear, ...] = ()

    @property
    def length_m(self) -> float:
        return self.polyline.length_m

    def intersections(self, reach_m: float = INTERSECTION_REACH_M) -> list[tuple[float, float]]:
        """Junction events grouped into places: (first s, last s) of runs of events within ``reach_m``."""
        out: list[tuple[float, float]] = []
        for j in self.junctions:
            if out and j.s_m - out[-1][1] <= reach_m:
                out[-1] = (out[-1][0], j.s_m)
            else:
                out.append((j.s_m, j.s_m))
        return out

    def layers(self, step_m: float = 1.0) -> SLayerDatabase:
        """The s-layer database along the service path (closed), with the route file's speed limit."""
        return SLayerDatabase.build(
            self.hdmap,
            self.lanelet_ids,
            step_m=step_m,
            closed=True,
            unmapped_speed_limit_mps=self.unmapped_speed_limit_mps,
            keep_clear=self.keep_clear,
            steerable=True,
        )


def load_route(path: str | Path) -> ServiceRoute:
    """Read a route file, load its map, snap its stops and route the service through them.

    Raises:
        ConfigError: a bad route file (see ``read_route_file``), an unknown map stop name.
        MapError: a bad map or projection; a stop farther than MAX_SNAP_M from every drivable lanelet.
        RoutingError: two consecutive stops with no route between them.
    """
    spec = read_route_file(path)
    hdmap = load_projected_map(spec.map_path, spec.projection)
    return build_service(spec, hdmap)


def campus_service() -> ServiceRoute:
    """The built-in campus service as a ServiceRoute: its ring loop and its four bays, exactly as
    ``campus_shuttle_loop`` and ``SLayerDatabase.build`` give them (the same path, s and layers)."""
    hdmap = load_campus_map()
    ids = campus_shuttle_loop(hdmap)
    polyline = route_polyline(hdmap, ids, closed=True)
    stops = []
    for bay in hdmap.stops:
        mid = bay.curb.xy_m[len(bay.curb.xy_m) // 2]
        lane = hdmap.lanelets[bay.lane_lanelet_id].centerline
        on_lane = lane.project(float(mid[0]), float(mid[1]))
        snap = Snap(
            lanelet_id=bay.lane_lanelet_id,
            lanelet_s_m=float(on_lane.s_m),
            offset_m=float(on_lane.d_m),
            distance_m=0.0,  # a mapped bay needs no snapping
        )
        s = polyline.project(float(mid[0]), float(mid[1])).s_m
        stops.append(
            ServiceStop(
                name=bay.id, x_m=float(mid[0]), y_m=float(mid[1]), snap=snap, route_s_m=float(s), source="bay"
            )
        )
    stops.sort(key=lambda st: st.route_s_m)
    starts = lanelet_starts_m(hdmap, ids)
    return ServiceRoute(
        name="campus",
        spec=None,
        hdmap=hdmap,
        lanelet_ids=ids,
        polyline=polyline,
        stops=tuple(stops),
        unmapped_speed_limit_mps=None,
        junctions=_junctions(hdmap, ids, starts),
    )


def build_service(spec: RouteSpec, hdmap: HDMap) -> ServiceRoute:
    """The service of ``spec`` on an already loaded ``hdmap`` (see ``load_route``)."""
    hdmap, gaps = bridge_gaps(hdmap, spec.connect_gaps_m)
    points = _stop_points(spec, hdmap)
    snaps = [_snap(hdmap, name, x, y, heading) for name, x, y, heading, _ in points]
    names = [p[0] for p in points]
    sources = [p[4] for p in points]
    xy = [(p[1], p[2]) for p in points]
    if spec.pattern is ServicePattern.OUT_AND_BACK:
        back = list(range(len(points) - 2, 0, -1))
        for k in back:
            lane = hdmap.lanelets[snaps[k].lanelet_id].centerline
            against = lane.heading_at(snaps[k].lanelet_s_m) + math.pi
            snaps.append(_snap(hdmap, names[k] + " (return)", *xy[k], against))
            names.append(names[k] + " (return)")
            sources.append(sources[k])
            xy.append(xy[k])
    if spec.waypoints_path is not None:
        path, at = _path_along_drive(spec, hdmap, snaps)
    else:
        path, at = _path_through(hdmap, snaps, names)
    # Lane changes keep off the platforms (and a shuttle length either side, to be straight there).
    half = spec.platform_length_m / 2.0 + VehicleGeometry().length_m
    keep_clear = tuple(
        KeepClear(x_m=x, y_m=y, half_length_m=half, lanelet_id=sn.lanelet_id)
        for sn, (x, y) in ((sn, _on_lane(hdmap, sn)) for sn in snaps)
    )
    polyline = route_polyline(
        hdmap,
        path,
        closed=True,
        unmapped_speed_limit_mps=spec.unmapped_speed_limit_mps,
        keep_clear=keep_clear,
        steerable=True,
    )
    pieces = route_pieces(hdmap, path, closed=True)
    starts = lanelet_starts_m(hdmap, path) * (polyline.length_m / lanelet_starts_m(hdmap, path)[-1])
    road = RoadOutline(hdmap)
    stops = []
    for name, (x, y), snap, k, source in zip(names, xy, snaps, at, sources, strict=True):
        hint = float(starts[k]) + max(snap.lanelet_s_m - pieces[k].s0_m, 0.0)
        s = polyline.project(*_on_lane(hdmap, snap), hint_s_m=hint, window_m=20.0).s_m
        # A platform is kept within one lap of route s (consumers compare s_start < s_end): one that
        # would straddle the loop's start slides forward, or back, to end there.
        snapped = float(s)
        door: tuple[float | None, float | None] = (None, None)
        if source != "bay":
            s, door = _dockable(
                polyline,
                snapped,
                spec,
                lambda c: _kerb_half(hdmap, road, polyline, c, spec.platform_length_m, path, starts),
            )
        half = spec.platform_length_m / 2 + PLATFORM_MARGIN_M
        s = min(max(float(s), half), polyline.length_m - half)
        stops.append(
            ServiceStop(
                name=name,
                x_m=x,
                y_m=y,
                snap=snap,
                route_s_m=float(s),
                source=source,
                moved_m=float(s) - snapped,
                door_gap_m=door[0],
                door_gap_given_m=door[1],
            )
        )
    bus_stops = tuple(
        _bus_stop(hdmap, road, polyline, st, spec.platform_length_m, path, starts) for st in stops
    )
    return ServiceRoute(
        name=spec.name,
        spec=spec,
        hdmap=dataclasses.replace(hdmap, stops=bus_stops),
        lanelet_ids=path,
        polyline=polyline,
        stops=tuple(stops),
        unmapped_speed_limit_mps=spec.unmapped_speed_limit_mps,
        bridged_gaps=gaps,
        junctions=_junctions(hdmap, path, starts),
        keep_clear=keep_clear,
    )


def _junctions(hdmap: HDMap, path: tuple[int, ...], starts: np.ndarray) -> tuple[RouteJunction, ...]:
    predecessors: dict[int, int] = {}
    for succ in hdmap.successor_ids.values():
        for lid in succ:
            predecessors[lid] = predecessors.get(lid, 0) + 1
    out = []
    n = len(path)
    for k, a in enumerate(path):
        b = path[(k + 1) % n]
        if b not in hdmap.successors(a):
            continue  # a lane change: no junction
        s = float(starts[k + 1]) % float(starts[-1])
        if len(hdmap.successors(a)) > 1:
            out.append(RouteJunction(s_m=s, kind="branch", lanelet_id=a))
        if predecessors.get(b, 0) > 1:
            out.append(RouteJunction(s_m=s, kind="merge", lanelet_id=b))
    return tuple(sorted(out, key=lambda j: j.s_m))


def _stop_points(spec: RouteSpec, hdmap: HDMap) -> list[tuple[str, float, float, float | None, str]]:
    """(name, x, y, heading or None, source) of each stop in service order."""
    if spec.stop_source is StopSource.FILE:
        out = []
        for entry in spec.stops:
            if entry.x_m is not None and entry.y_m is not None:
                x, y = entry.x_m, entry.y_m
            else:
                x, y = spec.projection.xy_from_latlon(np.array([entry.lat_deg]), np.array([entry.lon_deg]))[0]
            out.append((entry.name, float(x), float(y), heading_rad(entry), "file"))
        return out
    offered: dict[str, tuple[str, float, float, float | None, str]] = {}
    for bay in hdmap.stops:
        mid = bay.curb.xy_m[len(bay.curb.xy_m) // 2]
        lane = hdmap.lanelets[bay.lane_lanelet_id].centerline
        heading = lane.heading_at(lane.project(float(mid[0]), float(mid[1])).s_m)
        offered.setdefault(bay.id, (bay.id, float(mid[0]), float(mid[1]), heading, "bay"))
    for tagged in hdmap.tagged_stops:
        offered.setdefault(tagged.name, (tagged.name, tagged.x_m, tagged.y_m, None, tagged.source))
    if len(offered) < 2:
        raise MapError(
            f"map {hdmap.name!r}: expected at least two tagged stops (lastmile:bus_stop bays or nodes, "
            f"Autoware bus_stop_area), got {len(offered)}; list the stops in the route file instead"
        )
    if not spec.order:
        return list(offered.values())
    unknown = [n for n in spec.order if n not in offered]
    if unknown:
        raise ConfigError(
            f"{spec.source}: service.order: expected stop names the map tags ({sorted(offered)}), "
            f"got {unknown[0]!r}"
        )
    return [offered[n] for n in spec.order]


def _snap(hdmap: HDMap, name: str, x: float, y: float, heading: float | None) -> Snap:
    """The drivable lanelet nearest the point; among lanelets as near (two directions of one road),
    the one heading the stop's way, else the one the stop is on the right of (right-hand traffic).

    Raises:
        MapError: no drivable lanelet (heading the stop's way, when it has a heading) within MAX_SNAP_M.
    """
    best: tuple[tuple[float, int, float], Snap] | None = None
    for lid, info in hdmap.lanelets.items():
        if info.subtype not in DRIVABLE_SUBTYPES:
            continue
        poly = hdmap.polygon_of(lid)
        lo, hi = poly.min(axis=0) - MAX_SNAP_M, poly.max(axis=0) + MAX_SNAP_M
        if not (lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1]):
            continue
        inside = point_in_polygon(x, y, poly)
        dist = 0.0 if inside else abs(Polyline(poly, closed=True).project(x, y).d_m)
        if dist > MAX_SNAP_M:
            continue
        proj = info.centerline.project(x, y)
        s = min(max(float(proj.s_m), 0.0), info.centerline.length_m)
        if heading is not None:
            lane_heading = info.centerline.heading_at(s)
            if abs(math.remainder(lane_heading - heading, 2 * math.pi)) > math.pi / 2:
                continue
        key = (round(dist, 2), 0 if proj.d_m <= 0 else 1, abs(float(proj.d_m)))
        if best is None or key < best[0]:
            best = (key, Snap(lanelet_id=lid, lanelet_s_m=s, offset_m=float(proj.d_m), distance_m=dist))
    if best is None:
        way = "" if heading is None else f" heading {math.degrees(heading):.0f} deg"
        raise MapError(
            f"stop {name!r} at ({x:.1f}, {y:.1f}): expected a drivable lanelet{way} within {MAX_SNAP_M:g} m, "
            "got none (wrong coordinates or projection?)"
        )
    return best[1]


def _on_lane(hdmap: HDMap, snap: Snap) -> tuple[float, float]:
    x, y, _ = hdmap.lanelets[snap.lanelet_id].centerline.point_at(snap.lanelet_s_m)
    return x, y


def _path_through(hdmap: HDMap, snaps: list[Snap], names: list[str]) -> tuple[tuple[int, ...], list[int]]:
    """The closed lanelet path through the snapped stops in order, and each stop's index in it."""
    path = [snaps[0].lanelet_id]
    at = [0]
    for i in range(len(snaps)):
        a, b = snaps[i], snaps[(i + 1) % len(snaps)]
        try:
            leg = _leg(hdmap, a, b)
        except RoutingError:
            nb = names[(i + 1) % len(snaps)]
            raise RoutingError(
                f"route: expected a way from stop {names[i]!r} (lanelet {a.lanelet_id}) to stop {nb!r} "
                f"(lanelet {b.lanelet_id}) along the lanelets, got none (one-way lanes or a missing link)"
            ) from None
        path.extend(leg)
        if i + 1 < len(snaps):
            at.append(len(path) - 1)
    if len(path) > 1:
        path.pop()  # the last leg ends on the first stop's lanelet, where the path began
        at = [k % len(path) for k in at]  # a stop on that last lanelet is on the first one
    return _rotate_to_successor(hdmap, path, at)


def _rotate_to_successor(hdmap: HDMap, path: list[int], at: list[int]) -> tuple[tuple[int, ...], list[int]]:
    """Start the closed path after a successor link, so that it closes along one (not a lane change)."""
    n = len(path)
    for k in range(n):
        prev = path[k - 1]
        if n == 1 or path[k] in hdmap.successors(prev):
            return tuple(path[k:] + path[:k]), [(i - k) % n for i in at]
    raise RoutingError(
        f"route: expected the service path to follow a lane somewhere, got only lane changes {path}"
    )


def _leg(hdmap: HDMap, a: Snap, b: Snap) -> tuple[int, ...]:
    """Lanelets after ``a``'s up to and including ``b``'s (empty: ``b`` lies ahead on ``a``'s lanelet)."""
    if a.lanelet_id == b.lanelet_id and b.lanelet_s_m > a.lanelet_s_m + SAME_PLACE_M:
        return ()
    if a.lanelet_id != b.lanelet_id:
        return route(hdmap, a.lanelet_id, b.lanelet_id, lane_changes=True)[1:]
    # b is behind a on the same lanelet: leave it and come round again.
    best: tuple[int, ...] | None = None
    for nxt in hdmap.successors(a.lanelet_id):
        try:
            way = route(hdmap, nxt, a.lanelet_id, lane_changes=True)
        except RoutingError:
            continue
        if best is None or _length(hdmap, way) < _length(hdmap, best):
            best = way
    if best is None:
        raise RoutingError(f"route: expected a way round back to lanelet {a.lanelet_id}, got none")
    return best


def _length(hdmap: HDMap, ids: tuple[int, ...]) -> float:
    return float(sum(hdmap.lanelets[i].centerline.length_m for i in ids))


def _path_along_drive(spec: RouteSpec, hdmap: HDMap, snaps: list[Snap]) -> tuple[tuple[int, ...], list[int]]:
    """The closed lanelet path a recorded drive follows; stops must lie on it."""
    assert spec.waypoints_path is not None
    drive = read_waypoints(spec.waypoints_path)
    xy = spec.projection.xy_from_latlon(drive.lat_deg, drive.lon_deg)
    seq: list[int] = []
    for k, (x, y) in enumerate(xy.tolist()):
        nxt = xy[min(k + 1, len(xy) - 1)] if k + 1 < len(xy) else xy[k] + (xy[k] - xy[k - 1])
        heading = math.atan2(float(nxt[1] - y), float(nxt[0] - x))
        lid = _snap(hdmap, f"waypoint {k + 1}", float(x), float(y), heading).lanelet_id
        if not seq or seq[-1] != lid:
            seq.append(lid)
    path = [seq[0]]
    for a, b in itertools.pairwise([*seq, seq[0]]):
        if a != b:
            path.extend(route(hdmap, a, b, lane_changes=True)[1:])
    if len(path) > 1 and path[-1] == path[0]:
        path.pop()
    on_path = {lid: i for i, lid in enumerate(path)}
    at = []
    for snap in snaps:
        if snap.lanelet_id not in on_path:
            raise RoutingError(
                f"stop on lanelet {snap.lanelet_id}: expected it on the recorded drive's lanelets, "
                "got it off them"
            )
        at.append(on_path[snap.lanelet_id])
    return _rotate_to_successor(hdmap, path, at)


def find_gaps(hdmap: HDMap, gap_m: float) -> tuple[tuple[int, int, float], ...]:
    """(dead end, lanelet, gap m): lanelet ends with no successor and a drivable lanelet starting
    within ``gap_m`` that heads the same way (within GAP_HEADING_TOLERANCE_RAD)."""
    if gap_m <= 0:
        return ()
    ids = list(hdmap.lanelets)
    starts = np.array([hdmap.lanelets[i].centerline.xy_m[0] for i in ids])
    found = []
    for a in ids:
        line = hdmap.lanelets[a].centerline
        if hdmap.successors(a) or hdmap.lanelets[a].subtype not in DRIVABLE_SUBTYPES:
            continue  # only dead ends: a lanelet with successors is connected as mapped
        end = line.xy_m[-1]
        gaps = np.hypot(*(starts - end).T)
        for j in np.flatnonzero(gaps <= gap_m).tolist():
            b = ids[j]
            other = hdmap.lanelets[b]
            if other.subtype not in DRIVABLE_SUBTYPES or (abs(b) == abs(a) and b != a):
                continue
            bend = other.centerline.heading_at(0.0) - line.heading_at(line.length_m)
            turn = math.remainder(bend, 2 * math.pi)
            if abs(turn) <= GAP_HEADING_TOLERANCE_RAD:
                found.append((a, b, float(gaps[j])))
    return tuple(found)


def bridge_gaps(hdmap: HDMap, gap_m: float) -> tuple[HDMap, tuple[tuple[int, int, float], ...]]:
    """Join the gaps ``find_gaps`` finds.

    Each gap becomes a connector lanelet (a new id above every mapped one) whose bounds run straight
    from the dead end's bounds to the next lanelet's: the route file says the gap is road, so it is
    road everywhere the map is asked (routing, the drivable area of the referee and of the safety's
    ODD check, the stack's road region), not only a successor link the shuttle would cross off-map.

    Returns:
        The map with the connectors and their links, and (dead end, next lanelet, gap m) per bridge.
    """
    added = find_gaps(hdmap, gap_m)
    if not added:
        return hdmap, ()
    lanelets = dict(hdmap.lanelets)
    succ = {k: list(v) for k, v in hdmap.successor_ids.items()}
    next_id = max(abs(i) for i in hdmap.lanelets) + 1
    for a, b, _ in added:
        lanelets[next_id] = _connector(next_id, hdmap.lanelets[a], hdmap.lanelets[b])
        succ.setdefault(a, []).append(next_id)
        succ[next_id] = [b]
        next_id += 1
    return (
        dataclasses.replace(hdmap, lanelets=lanelets, successor_ids={k: tuple(v) for k, v in succ.items()}),
        tuple(added),
    )


CONNECTOR_STEP_M = 0.5  # vertex spacing of a connector's bounds (the gap is short; any spacing is exact)
MIN_BOUND_M = 1e-3


def _connector(lid: int, a: LaneletInfo, b: LaneletInfo) -> LaneletInfo:
    """A lanelet over the gap from ``a``'s end to ``b``'s start: straight bounds, ``a``'s types; its
    limit is the lower mapped one of the two (NaN when neither states one: the route file's applies)."""

    centre = b.centerline.xy_m[0] - a.centerline.xy_m[-1]
    if float(np.hypot(*centre)) < MIN_BOUND_M:
        # A dead end exactly where the next lane starts (the map drew the joint with separate points):
        # the connector runs along the dead end's own heading.
        heading = a.centerline.heading_at(a.centerline.length_m)
        centre = np.array([math.cos(heading), math.sin(heading)])
    along = centre / float(np.hypot(*centre))

    def across(p: np.ndarray, q: np.ndarray) -> Polyline:
        if float(np.hypot(*(q - p))) < MIN_BOUND_M:
            # Bounds that meet (a lane narrowing to a point) still need a line: a millimetre along.
            return Polyline(np.vstack([p, p + MIN_BOUND_M * along]))
        n = max(2, math.ceil(float(np.hypot(*(q - p))) / CONNECTOR_STEP_M) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        return Polyline((1.0 - t) * p + t * q)

    limits = [v for v in (a.speed_limit_mps, b.speed_limit_mps) if math.isfinite(v)]
    return LaneletInfo(
        id=lid,
        centerline=across(a.centerline.xy_m[-1], b.centerline.xy_m[0]),
        left=across(a.left.xy_m[-1], b.left.xy_m[0]),
        right=across(a.right.xy_m[-1], b.right.xy_m[0]),
        speed_limit_mps=min(limits) if limits else math.nan,
        subtype=a.subtype,
        left_type=a.left_type,
        right_type=a.right_type,
    )


def _dockable(
    polyline: Polyline, s_m: float, spec: RouteSpec, kerb_half: Callable[[float], float]
) -> tuple[float, tuple[float, float]]:
    """Where a kerbside stop given at route ``s_m`` goes, and (door gap there, door gap where given).

    A platform's door gap (``curb_fit.rest_door_gap_m`` against its kerb ``kerb_half``, worst over
    a door DOOR_SPREAD_M either side of the platform's middle) above ``spec.max_door_gap_m`` is a
    bend the straight body cannot lie along with the door at the kerb, and a bend towards the kerb
    over the settle run before the spot (SETTLE_RUN_M) off-tracks the rear axle onto it: the stop
    moves to the nearest
    place (every MOVE_STEP_M, downstream first on a tie, at most ``spec.max_stop_move_m``) that keeps
    it, and whose kerb is no nearer the route than where it was given (a move must not trade a bend
    for less room to pull over). No such place: it stays, and its door gap says what to expect.
    """
    geometry = VehicleGeometry()
    wheelbase = geometry.wheelbase_m
    door_from_rear = geometry.length_m / 2.0 - geometry.rear_overhang_m
    # The rear wheels are kept straight at a kerb, so on a bend towards the kerb (a right turn for a
    # kerb on the right) the rear axle off-tracks towards it by wheelbase^2 / 2R; over the settle run
    # before the spot that must stay within the gap the pull-over keeps: R >= wheelbase^2 / (2 gap).
    toward_kerb_limit = 2.0 * CURB_GAP_TARGET_M / wheelbase**2

    def offtracks(c: float) -> bool:
        rear = c - door_from_rear
        for q in np.arange(rear - SETTLE_RUN_M, rear + 1e-9, MOVE_STEP_M).tolist():
            turn = (polyline.heading_at(q + wheelbase) - polyline.heading_at(q) + math.pi) % (
                2 * math.pi
            ) - math.pi
            if -turn / wheelbase > toward_kerb_limit:
                return True
        return False

    def door_gap(c: float, half: float) -> float:
        doors = (c - DOOR_SPREAD_M, c, c + DOOR_SPREAD_M)
        return max(rest_door_gap_m(polyline, q, -half, CURB_GAP_TARGET_M, geometry) for q in doors)

    given_half = kerb_half(s_m)
    given = door_gap(s_m, given_half)
    # First a place where the door keeps the limit and the settle run does not off-track the rear
    # onto the kerb; failing that (a kerb on a long bend), one where at least the door does.
    for check_offtrack in (True, False):
        if given <= spec.max_door_gap_m and not (check_offtrack and offtracks(s_m)):
            return s_m, (given, given)
        for k in range(1, int(spec.max_stop_move_m / MOVE_STEP_M) + 1):
            for c in (s_m + k * MOVE_STEP_M, s_m - k * MOVE_STEP_M):
                if check_offtrack and offtracks(c):
                    continue
                half = kerb_half(c)
                if half < given_half:
                    continue
                gap = door_gap(c, half)
                if gap <= spec.max_door_gap_m:
                    return c, (gap, given)
    return s_m, (given, given)


def _kerb_half(
    hdmap: HDMap,
    road: RoadOutline,
    polyline: Polyline,
    s_m: float,
    platform_m: float,
    path: tuple[int, ...],
    starts: np.ndarray,
) -> float:
    """Distance right of the route to a kerbside platform's edge centred at route ``s_m`` (see
    ``_bus_stop``)."""

    def lane_half(sk: float) -> float:
        x, y, _ = polyline.point_at(sk)
        k = int(np.clip(np.searchsorted(starts, sk % polyline.length_m, side="right") - 1, 0, len(path) - 1))
        lid = hdmap.lanelet_at(x, y)
        lane = hdmap.lanelets[lid if lid is not None and lid in hdmap.lanelets else path[k]]
        return abs(float(lane.right.project(x, y).d_m))

    on_platform = np.arange(s_m - platform_m / 2, s_m + platform_m / 2, 1.0).tolist()
    half = min(lane_half(sk) for sk in on_platform)
    # The road's edge right of each approach point: the first probe (every ROAD_EDGE_STEP_M) off it.
    approach = np.arange(s_m - platform_m / 2 - KERBSIDE_APPROACH_M, on_platform[0], 1.0)
    steps = np.arange(0.0, half, ROAD_EDGE_STEP_M)
    if len(approach) and len(steps):
        xy = polyline.points_at(approach)
        heading = np.array([polyline.heading_at(float(sk)) for sk in approach])
        right = np.c_[np.sin(heading), -np.cos(heading)]
        probes = xy[:, None, :] + steps[None, :, None] * right[:, None, :]
        on_road = road.contains(probes.reshape(-1, 2)).reshape(len(approach), len(steps))
        first_off = np.where(on_road.all(axis=1), half, steps[np.argmin(on_road, axis=1)])
        half = min(half, float(first_off.min()))
    return half


def _bus_stop(
    hdmap: HDMap,
    road: RoadOutline,
    polyline: Polyline,
    stop: ServiceStop,
    platform_m: float,
    path: tuple[int, ...],
    starts: np.ndarray,
) -> BusStop:
    """A mapped bay as it is; any other stop as a kerbside stop on its lane's right edge.

    The edge is the lane's right bound where the lane is narrowest along the platform, and no farther
    right than the road's edge anywhere on the pull-over's approach (KERBSIDE_APPROACH_M): a lane
    that widens at the stop (a bay drawn as a bulge of the lane) would otherwise put the spot so far
    right that the shuttle's corner leaves the narrower road on its way in. The approach may cross
    lanes (a lane change before the stop), so there the limit is the road's edge, not a lane's.
    """
    for bay in hdmap.stops:
        if stop.source == "bay" and bay.id == stop.name:
            return bay

    half = _kerb_half(hdmap, road, polyline, stop.route_s_m, platform_m, path, starts)
    s = stop.route_s_m + np.linspace(-platform_m / 2, platform_m / 2, max(int(platform_m), 2) + 1)
    edge = []
    for sk in s.tolist():
        x, y, h = polyline.point_at(sk)
        edge.append((x + half * math.sin(h), y - half * math.cos(h)))  # right of the direction of travel
    return BusStop(
        id=stop.name,
        name=stop.name,
        lane_lanelet_id=stop.snap.lanelet_id,
        bay_lanelet_id=stop.snap.lanelet_id,
        curb=Polyline(np.array(edge)),
    )
