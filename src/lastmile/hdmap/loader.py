"""Reads a Lanelet2 OSM map through the ``lanelet2`` package into the typed ``HDMap``.

Lanelet2 does the parsing, the projection, the traffic rules (speed limits) and the routing graph
(which lanelet follows which); this module only copies what the stack needs into plain arrays.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterable
from functools import lru_cache
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import lanelet2.core as ll2
import lanelet2.routing as ll2_routing
import lanelet2.traffic_rules as ll2_rules
import numpy as np
from lanelet2.io import Origin, loadRobust
from lanelet2.projection import UtmProjector
from scipy.spatial import ConvexHull

from lastmile.core.errors import MapError
from lastmile.core.geometry import FloatArray
from lastmile.core.polyline import Polyline
from lastmile.core.traffic_light_messages import MapTrafficLight
from lastmile.hdmap import campus_layout
from lastmile.hdmap.model import (
    AllWayStop,
    BusStop,
    Crosswalk,
    HDMap,
    Landmark,
    LaneletInfo,
    MapArea,
    RightOfWayRule,
    SignRule,
    StopLine,
    TaggedStop,
    TrafficSignal,
    is_curb_type,
)
from lastmile.hdmap.projection import MapProjection, ProjectionKind

CAMPUS_OSM = Path(__file__).with_name("data") / "campus.osm"
BUS_STOP_TAG = "lastmile:bus_stop"
# Stop-sign types of a ``traffic_sign`` rule: the German VZ 206 (Lanelet2's own ``de206``), the US MUTCD
# R1-1 (``us:R1-1`` / ``usR1-1``), and Autoware's and plain spellings.
STOP_SIGN_TYPES = frozenset({"de206", "us:r1-1", "usr1-1", "r1-1", "stop_sign", "stop"})
DEFAULT_HEAD_HEIGHT_M = 1.0  # a three-bulb head, for maps whose traffic_light line strings carry no height


def load_map(path: str | Path, origin_lat_deg: float, origin_lon_deg: float, name: str = "") -> HDMap:
    """Load a Lanelet2 OSM file projected (UTM) about the given origin.

    Raises:
        MapError: the file is missing, is not a Lanelet2 map, or Lanelet2 reports parse errors.
    """
    return load_projected_map(
        path,
        MapProjection(kind=ProjectionKind.UTM, origin_lat_deg=origin_lat_deg, origin_lon_deg=origin_lon_deg),
        name,
    )


def load_projected_map(path: str | Path, projection: MapProjection, name: str = "") -> HDMap:
    """Load a Lanelet2 OSM file in the given projection (UTM about an origin, an MGRS grid, or local).

    MGRS and local maps take each node's ``local_x``/``local_y`` tags where it has them (Autoware's
    format); MGRS maps project the other nodes from their latitude/longitude into the grid square.

    Raises:
        MapError: the file is missing or not Lanelet2 OSM (OpenDRIVE and ``.osm_xy`` files are named as
            needing a conversion), Lanelet2 reports parse errors, the map has no lanelets, or the
            projection does not fit the map (nodes far from a UTM origin, ``local_x``/``local_y`` that
            disagree with the nodes' latitude/longitude in the MGRS grid, a local map without them).
    """
    path = Path(path)
    if not path.is_file():
        raise MapError(f"map {str(path)!r}: expected a Lanelet2 .osm file, got no such file")
    _check_format(path)
    origin = _loading_origin(projection)
    projector = UtmProjector(Origin(*origin))
    try:
        lmap, errors = loadRobust(str(path), projector)
    except RuntimeError as exc:  # lanelet2 raises ParseError (a RuntimeError) on XML it cannot read
        raise MapError(f"map {str(path)!r}: expected Lanelet2 OSM XML, lanelet2 said: {exc}") from exc
    unknown_rules, errors = _split_unknown_rules(errors)
    if errors:
        shown = "; ".join(errors[:3]) + (f" (and {len(errors) - 3} more)" if len(errors) > 3 else "")
        raise MapError(
            f"map {str(path)!r}: expected a well-formed Lanelet2 map, got {len(errors)} errors: {shown}"
        )
    if len(lmap.laneletLayer) == 0:
        raise MapError(f"map {str(path)!r}: expected at least one lanelet, got none")
    if projection.kind is ProjectionKind.UTM:
        _check_near_origin(lmap, path, projection)
    else:
        _to_local_frame(lmap, path, projection, projector)
    hdmap = _convert(lmap, name or path.stem)
    if not unknown_rules:
        return hdmap
    names = _autoware_bus_stop_names(path) if AUTOWARE_BUS_STOP in dict(unknown_rules) else {}
    tagged = tuple(
        dataclasses.replace(t, name=names.get(t.id, t.name)) if t.source.startswith("autoware:") else t
        for t in hdmap.tagged_stops
    )
    return dataclasses.replace(hdmap, unread_rules=unknown_rules, tagged_stops=tagged)


_UNKNOWN_RULE = re.compile(r"No regulatory element found that implements rule (\S+)")


def _split_unknown_rules(errors: list[str]) -> tuple[tuple[tuple[str, int], ...], list[str]]:
    """Lanelet2 reports the rules it has no class for (Autoware's bus_stop_area, detection_area, ...)
    as parse errors and leaves them out; they are extensions, not a broken map. They are counted (map
    check lists them) and only the other errors remain errors."""
    counts: dict[str, int] = {}
    rest = []
    for err in errors:
        found = _UNKNOWN_RULE.search(err)
        if found:
            counts[found.group(1)] = counts.get(found.group(1), 0) + 1
        elif not err.startswith("Errors ocurred while parsing"):  # Lanelet2's header line (sic)
            rest.append(err)
    if not counts:
        return (), list(errors)
    return tuple(sorted(counts.items())), rest


def _autoware_bus_stop_names(path: Path) -> dict[int, str]:
    """The ``name`` of each Autoware bus_stop_area rule, by the ids of the areas it refers to (Lanelet2
    drops the rule itself, see ``_split_unknown_rules``)."""
    out: dict[int, str] = {}
    for _, elem in ElementTree.iterparse(path):
        if elem.tag != "relation":
            continue
        tags = {t.get("k"): t.get("v") for t in elem.iter("tag")}
        if tags.get("subtype") == AUTOWARE_BUS_STOP and tags.get("name"):
            for member in elem.iter("member"):
                if member.get("role") == "refers":
                    out[int(member.get("ref", "0"))] = str(tags["name"])
        elem.clear()
    return out


def _check_format(path: Path) -> None:
    """OpenDRIVE and Lanelet2's local-xy OSM variant need a conversion; name it instead of a parse error."""
    suffix = path.suffix.lower()
    if suffix == ".xodr":
        raise MapError(
            f"map {str(path)!r}: expected a Lanelet2 .osm file, got OpenDRIVE (.xodr); convert it to "
            "Lanelet2 first (for example with CARLA's or Autoware's OpenDRIVE-to-Lanelet2 converter)"
        )
    if suffix == ".osm_xy":
        raise MapError(
            f"map {str(path)!r}: expected a Lanelet2 .osm file with latitude/longitude or local_x/local_y "
            "node tags, got .osm_xy (metric x/y in the lat/lon fields); convert it to .osm first"
        )


def _loading_origin(projection: MapProjection) -> tuple[float, float]:
    """Where Lanelet2's UTM projector is anchored while parsing (MGRS and local maps are re-framed after)."""
    if projection.kind is ProjectionKind.UTM:
        return projection.origin_lat_deg, projection.origin_lon_deg
    if projection.kind is ProjectionKind.MGRS:
        # The square's centre: Lanelet2's projector is only a way back to each node's lat/lon here.
        lat, lon = projection.latlon_from_xy(np.array([[50_000.0, 50_000.0]]))[0]
        return float(lat), float(lon)
    return 0.0, 0.0


FAR_FROM_ORIGIN_M = 100_000.0  # a map is a town at most; a UTM origin this far off is the wrong one
LOCAL_TAG_TOLERANCE_M = 1.0  # Autoware's local_x/local_y are written to 0.1 mm; a wrong grid is 100 km off


def _check_near_origin(lmap: Any, path: Path, projection: MapProjection) -> None:
    xy = np.array([(p.x, p.y) for p in lmap.pointLayer], dtype=float).reshape(-1, 2)
    far = float(np.max(np.hypot(xy[:, 0], xy[:, 1]))) if len(xy) else 0.0
    if far > FAR_FROM_ORIGIN_M:
        raise MapError(
            f"map {str(path)!r}: expected its nodes within {FAR_FROM_ORIGIN_M / 1000:g} km of the projection "
            f"origin ({projection.describe()}), got one {far / 1000:.0f} km away (wrong origin?)"
        )


def _to_local_frame(lmap: Any, path: Path, projection: MapProjection, projector: Any) -> None:
    """Move every node into the MGRS square's (or the local) frame, from its tags or its lat/lon."""
    tagged: list[tuple[Any, float, float]] = []
    untagged: list[Any] = []
    for p in lmap.pointLayer:
        if "local_x" in p.attributes and "local_y" in p.attributes:
            try:
                tagged.append((p, float(str(p.attributes["local_x"])), float(str(p.attributes["local_y"]))))
            except ValueError:
                raise MapError(
                    f"map {str(path)!r} node {p.id}: expected numeric local_x/local_y, got "
                    f"{p.attributes['local_x']!s}/{p.attributes['local_y']!s}"
                ) from None
        else:
            untagged.append(p)
    if projection.kind is ProjectionKind.LOCAL:
        if untagged:
            raise MapError(
                f"map {str(path)!r}: expected local_x/local_y tags on every node of a local-coordinate "
                f"map, got {len(untagged)} nodes without them (node {untagged[0].id}); give a geographic "
                "projection"
            )
    else:
        everyone = [p for p, _, _ in tagged] + untagged
        gps = [projector.reverse(ll2.BasicPoint3d(p.x, p.y, p.z)) for p in everyone]
        from_latlon = projection.xy_from_latlon(
            np.array([g.lat for g in gps]), np.array([g.lon for g in gps])
        )
        # Some Autoware maps leave lat/lon at 0 beside local_x/local_y: nothing to check those against.
        geo = np.array([abs(g.lat) + abs(g.lon) > 1e-9 for g in gps[: len(tagged)]], dtype=bool)
        if geo.any():
            tags = np.array([(x, y) for _, x, y in tagged])[geo]
            gap = float(np.median(np.hypot(*(from_latlon[: len(tagged)][geo] - tags).T)))
            if gap > LOCAL_TAG_TOLERANCE_M:
                raise MapError(
                    f"map {str(path)!r}: expected local_x/local_y to agree with the nodes' latitude/"
                    f"longitude in {projection.describe()}, got a median gap of {gap:.0f} m "
                    "(wrong MGRS grid?)"
                )
        for p, (x, y) in zip(untagged, from_latlon[len(tagged) :], strict=True):
            p.x, p.y = float(x), float(y)
    for p, x, y in tagged:
        p.x, p.y = x, y


@lru_cache(maxsize=1)
def load_campus_map() -> HDMap:
    """The built-in campus map (``campus.osm``, generated by ``lastmile.hdmap.campus``)."""
    return load_map(CAMPUS_OSM, campus_layout.ORIGIN_LAT_DEG, campus_layout.ORIGIN_LON_DEG, name="campus")


def _attr(attributes: Any, key: str, default: str) -> str:
    """A Lanelet2 attribute as a string, or ``default`` (AttributeMap has no ``get``)."""
    return str(attributes[key]) if key in attributes else default


def _xy(points: Iterable[Any]) -> FloatArray:
    return np.array([(p.x, p.y) for p in points], dtype=float).reshape(-1, 2)


def _polyline(points: Iterable[Any]) -> Polyline | None:
    xy = _xy(points)
    if len(xy) < 2 or (float(np.hypot(*(xy[-1] - xy[0]))) < 1e-6 and len(xy) < 3):
        return None
    return Polyline(xy)


def _type(ls: Any) -> str:
    attrs = ls.attributes
    kind = _attr(attrs, "type", "")
    return f"{kind}:{attrs['subtype']}" if "subtype" in attrs else kind


def _convert(lmap: Any, name: str) -> HDMap:
    rules = ll2_rules.create(ll2_rules.Locations.Germany, ll2_rules.Participants.Vehicle)
    topology = _topology(lmap, rules)
    lanelets = topology.lanelets
    stop_lines, all_way_stops = _regulatory(lmap, lanelets, topology.successor_ids)
    return HDMap(
        name=name,
        lanelets=lanelets,
        successor_ids=topology.successor_ids,
        neighbour_ids=topology.neighbour_ids,
        conflict_ids=topology.conflict_ids,
        stops=_bus_stops(lmap, lanelets),
        crosswalks=_crosswalks(lanelets),
        stop_lines=stop_lines,
        all_way_stops=all_way_stops,
        landmarks=_landmarks(lmap),
        curbs=_curbs(lmap),
        signals=_signals(lmap, stop_lines),
        tagged_stops=_tagged_stops(lmap),
        priority_lanelet_ids=_priority_lanelet_ids(lmap, lanelets),
        right_of_way_rules=_right_of_way_rules(lmap, lanelets),
        sign_rules=_sign_rules(lmap, lanelets),
        areas=_areas(lmap),
    )


@dataclasses.dataclass(frozen=True, slots=True)
class _Topology:
    """The directed lanelets and their relations, each relation limited to lanelets that were kept."""

    lanelets: dict[int, LaneletInfo]
    successor_ids: dict[int, tuple[int, ...]]
    neighbour_ids: dict[int, tuple[int, ...]]
    conflict_ids: dict[int, tuple[int, ...]]


def _topology(lmap: Any, rules: Any) -> _Topology:
    graph = ll2_routing.RoutingGraph(lmap, rules)
    lanelets: dict[int, LaneletInfo] = {}
    successors: dict[int, tuple[int, ...]] = {}
    beside: dict[int, tuple[int, ...]] = {}
    crossing: dict[int, tuple[int, ...]] = {}
    for lanelet in lmap.laneletLayer:
        for directed in _directions(lanelet, rules):
            lid = _directed_id(directed)
            info = _lanelet_info(directed, lid, rules)
            if info is None:
                continue
            lanelets[lid] = info
            successors[lid] = tuple(_directed_id(f) for f in graph.following(directed, False))
            sides = (graph.left(directed), graph.right(directed))
            beside[lid] = tuple(_directed_id(n) for n in sides if n is not None)
            crossing[lid] = tuple(
                _directed_id(c) for c in graph.conflicting(directed) if isinstance(c, ll2.ConstLanelet)
            )
    return _Topology(
        lanelets=lanelets,
        successor_ids=_kept(successors, lanelets, drop_empty=False),
        neighbour_ids=_kept(beside, lanelets, drop_empty=True),
        conflict_ids=_kept(crossing, lanelets, drop_empty=True),
    )


def _directions(lanelet: Any, rules: Any) -> list[Any]:
    """A two-way lanelet is two directed lanelets to a router: the reversed one gets the negated id."""
    if not rules.isOneWay(lanelet) and rules.canPass(lanelet.invert()):
        return [lanelet, lanelet.invert()]
    return [lanelet]


def _kept(
    relation: dict[int, tuple[int, ...]], lanelets: dict[int, LaneletInfo], *, drop_empty: bool
) -> dict[int, tuple[int, ...]]:
    kept = {k: tuple(s for s in v if s in lanelets) for k, v in relation.items() if k in lanelets}
    return {k: v for k, v in kept.items() if v} if drop_empty else kept


def _crosswalks(lanelets: dict[int, LaneletInfo]) -> tuple[Crosswalk, ...]:
    return tuple(
        Crosswalk(id=lid, polygon=info.polygon(), width_m=_mean_gap(info.left, info.right))
        for lid, info in sorted(lanelets.items())
        if info.subtype == "crosswalk"
    )


def _curbs(lmap: Any) -> tuple[Polyline, ...]:
    return tuple(
        line
        for ls in sorted(lmap.lineStringLayer, key=lambda ls: ls.id)
        if is_curb_type(_type(ls)) and (line := _polyline(ls)) is not None
    )


def _priority_lanelet_ids(lmap: Any, lanelets: dict[int, LaneletInfo]) -> frozenset[int]:
    return frozenset(
        lid
        for rule in lmap.regulatoryElementLayer
        if isinstance(rule, ll2.RightOfWay)
        for ll in (*rule.rightOfWayLanelets(), *rule.yieldLanelets())
        if (lid := _directed_id(ll)) in lanelets
    )


def _right_of_way_rules(lmap: Any, lanelets: dict[int, LaneletInfo]) -> tuple[RightOfWayRule, ...]:
    """Every ``right_of_way`` rule with the kept lanelets it gives priority to and makes yield."""

    def kept(lls: Iterable[Any]) -> tuple[int, ...]:
        return tuple(lid for ll in lls if (lid := _directed_id(ll)) in lanelets)

    return tuple(
        RightOfWayRule(
            id=rule.id,
            name=_attr(rule.attributes, "name", ""),
            priority_lanelet_ids=kept(rule.rightOfWayLanelets()),
            yield_lanelet_ids=kept(rule.yieldLanelets()),
            stop_line_id=rule.stopLine.id if rule.stopLine is not None else None,
        )
        for rule in sorted(lmap.regulatoryElementLayer, key=lambda r: r.id)
        if isinstance(rule, ll2.RightOfWay)
    )


def _sign_rules(lmap: Any, lanelets: dict[int, LaneletInfo]) -> tuple[SignRule, ...]:
    """Every ``traffic_sign`` / ``speed_limit`` rule with the kept lanelets that reference it."""
    refs: dict[int, list[int]] = {}
    for lanelet in lmap.laneletLayer:
        for rule in lanelet.regulatoryElements:
            if isinstance(rule, ll2.TrafficSign):
                refs.setdefault(rule.id, []).extend(
                    lid for lid in (int(lanelet.id), -int(lanelet.id)) if lid in lanelets
                )
    return tuple(
        SignRule(
            id=rule.id,
            sign_type=str(rule.type()),
            speed_limit=isinstance(rule, ll2.SpeedLimit),
            lanelet_ids=tuple(sorted(set(refs.get(rule.id, ())))),
        )
        for rule in sorted(lmap.regulatoryElementLayer, key=lambda r: r.id)
        if isinstance(rule, ll2.TrafficSign)
    )


def _areas(lmap: Any) -> tuple[MapArea, ...]:
    return tuple(
        MapArea(
            id=a.id,
            subtype=_attr(a.attributes, "subtype", ""),
            polygon=_xy(p for ls in a.outerBound for p in ls),
            name=_attr(a.attributes, "name", ""),
        )
        for a in sorted(lmap.areaLayer, key=lambda a: a.id)
    )


def _directed_id(lanelet: Any) -> int:
    return -int(lanelet.id) if lanelet.inverted() else int(lanelet.id)


def _lanelet_info(lanelet: Any, lid: int, rules: Any) -> LaneletInfo | None:
    attrs = lanelet.attributes
    left, right, centre = (
        _polyline(lanelet.leftBound),
        _polyline(lanelet.rightBound),
        _polyline(lanelet.centerline),
    )
    if left is None or right is None or centre is None:
        return None  # a degenerate lanelet (all bound points coincide) has no extent to drive or draw
    if centre.length_m < CENTRELINE_SHORTCUT_RATIO * min(left.length_m, right.length_m):
        centre = _mid_line(left, right)
    return LaneletInfo(
        id=lid,
        centerline=centre,
        left=left,
        right=right,
        speed_limit_mps=_mapped_speed_limit_mps(lanelet, rules),
        subtype=_attr(attrs, "subtype", "road"),
        left_type=_type(lanelet.leftBound),
        right_type=_type(lanelet.rightBound),
        turn=_attr(attrs, "turn_direction", ""),
        bus_stop_id=_attr(attrs, BUS_STOP_TAG, ""),
        left_bound_id=int(lanelet.leftBound.id),
        right_bound_id=int(lanelet.rightBound.id),
    )


CENTRELINE_SHORTCUT_RATIO = 0.5
"""Lanelet2 builds a centre line as the shortest path through the lanelet's area; on a lanelet whose
bounds close into a ring (a whole loop in one lanelet, as on the BITS campus map) that path can jump
the few metres from start to end instead of going round. A centre line under half the shorter bound's
length is such a shortcut, and the mid-line of the bounds replaces it."""


def _mid_line(left: Polyline, right: Polyline) -> Polyline:
    """The points half-way between the bounds at equal fractions of their lengths."""
    n = max(len(left.xy_m), len(right.xy_m)) * 2
    frac = np.linspace(0.0, 1.0, n)
    mid = 0.5 * (left.points_at(frac * left.length_m) + right.points_at(frac * right.length_m))
    keep = np.r_[True, np.hypot(*np.diff(mid, axis=0).T) > 1e-6]
    return Polyline(mid[keep])


def _mapped_speed_limit_mps(lanelet: Any, rules: Any) -> float:
    """The lanelet's speed limit where the map states one (its ``speed_limit`` tag or a speed-limit rule),
    else NaN.

    Lanelet2's traffic rules answer every lanelet, falling back to the country's default for its
    ``location`` (50 km/h urban in Germany); a shuttle must not take that guess for a mapped limit,
    so an untagged lanelet stays unknown and the route file's limit (or an error) decides.
    """
    stated = "speed_limit" in lanelet.attributes or any(
        isinstance(rule, ll2.SpeedLimit) for rule in lanelet.regulatoryElements
    )
    if not stated:
        return math.nan
    limit = float(rules.speedLimit(lanelet).speedLimitMPS)
    if not (math.isfinite(limit) and limit > 0):  # Lanelet2 reads "fast" as 0 and "-5" as -5 km/h
        tag = _attr(lanelet.attributes, "speed_limit", "a speed-limit rule")
        raise MapError(
            f"lanelet {lanelet.id}: expected a positive speed_limit (such as '30' or '30 km/h'), got {tag!r}"
        )
    return limit


def _mean_gap(a: Polyline, b: Polyline) -> float:
    return float(np.mean([abs(b.project(float(x), float(y)).d_m) for x, y in a.xy_m]))


def _bus_stops(lmap: Any, lanelets: dict[int, LaneletInfo]) -> tuple[BusStop, ...]:
    """Bays tagged ``lastmile:bus_stop``: the lane beside shares the bay's left bound."""
    by_right_bound = {ll.rightBound.id: ll.id for ll in lmap.laneletLayer if ll.id in lanelets}
    stops = []
    for lanelet in sorted(lmap.laneletLayer, key=lambda ll: ll.id):
        info = lanelets.get(lanelet.id)
        if info is None or not info.bus_stop_id:
            continue
        lane_id = by_right_bound.get(lanelet.leftBound.id)
        if lane_id is None:
            raise MapError(
                f"bus stop {info.bus_stop_id!r}: expected its bay lanelet {lanelet.id} to share its left "
                "bound with a lane's right bound, got no such lane"
            )
        # The platform is where the bay reaches full depth; the tapers either side are for entering.
        depth = np.array([abs(info.left.project(float(x), float(y)).d_m) for x, y in info.right.xy_m])
        platform = info.right.xy_m[depth >= depth.max() - 0.02]
        if len(platform) < 2:
            raise MapError(f"bus stop {info.bus_stop_id!r}: expected a platform curb, got a bay without one")
        name = _attr(lanelet.attributes, "name", info.bus_stop_id)
        stops.append(
            BusStop(
                id=info.bus_stop_id,
                name=name,
                lane_lanelet_id=lane_id,
                bay_lanelet_id=lanelet.id,
                curb=Polyline(platform),
            )
        )
    return tuple(sorted(stops, key=lambda s: s.id))


AUTOWARE_BUS_STOP = "bus_stop_area"
_AREA_LIKE = (ll2.Polygon3d, ll2.ConstPolygon3d, ll2.LineString3d, ll2.ConstLineString3d)


def _tagged_stops(lmap: Any) -> tuple[TaggedStop, ...]:
    """Nodes tagged ``lastmile:bus_stop`` and Autoware bus-stop areas (as rules or bare polygons)."""
    out = [
        TaggedStop(id=p.id, name=str(p.attributes[BUS_STOP_TAG]), x_m=p.x, y_m=p.y, source=BUS_STOP_TAG)
        for p in sorted(lmap.pointLayer, key=lambda p: p.id)
        if BUS_STOP_TAG in p.attributes
    ]
    polygons: dict[int, tuple[Any, str]] = {}
    for rule in sorted(lmap.regulatoryElementLayer, key=lambda r: r.id):
        if _attr(rule.attributes, "subtype", "") != AUTOWARE_BUS_STOP:
            continue
        params = rule.parameters  # a RuleParameterMap: no get()
        for prim in params["refers"] if "refers" in params else []:  # noqa: SIM401
            if isinstance(prim, _AREA_LIKE):
                polygons.setdefault(prim.id, (prim, _attr(rule.attributes, "name", "")))
    for poly in lmap.polygonLayer:
        if _attr(poly.attributes, "type", "") == AUTOWARE_BUS_STOP:
            polygons.setdefault(poly.id, (poly, ""))
    for pid in sorted(polygons):
        prim, rule_name = polygons[pid]
        xy = _xy(prim)
        if len(xy) == 0:
            continue
        name = _attr(prim.attributes, "name", "") or rule_name or f"bus_stop_area {pid}"
        cx, cy = xy.mean(axis=0)
        source = "autoware:" + AUTOWARE_BUS_STOP
        out.append(TaggedStop(id=pid, name=name, x_m=float(cx), y_m=float(cy), source=source))
    return tuple(out)


def _regulatory(
    lmap: Any, lanelets: dict[int, LaneletInfo], successors: dict[int, tuple[int, ...]]
) -> tuple[tuple[StopLine, ...], tuple[AllWayStop, ...]]:
    """Stop lines of every rule that has them; all-way stops with the box their entries cross."""
    lines: dict[int, StopLine] = {}
    stops = []

    def add(line: Any, lanelet_id: int, rule: Any) -> None:
        if line is None:
            return
        new = StopLine(
            id=line.id,
            line=_xy(line)[[0, -1]],
            lanelet_id=lanelet_id,
            all_way_stop_id=rule.id if isinstance(rule, ll2.AllWayStop) else None,
            signal_id=rule.id if isinstance(rule, ll2.TrafficLight) else None,
            stop_sign_id=rule.id if is_stop_sign_rule(rule) else None,
            right_of_way_id=rule.id if isinstance(rule, ll2.RightOfWay) else None,
        )
        old = lines.get(line.id)
        if old is None:
            lines[line.id] = new
        elif old.stop_sign_id is None and new.stop_sign_id is not None:
            # An all-way stop's or a signal's line that a stop sign's rule also names: both hold.
            lines[line.id] = dataclasses.replace(old, stop_sign_id=new.stop_sign_id)

    for lanelet in sorted(lmap.laneletLayer, key=lambda ll: ll.id):
        if lanelet.id not in lanelets:
            continue
        for rule in lanelet.regulatoryElements:
            add(_stop_line_of(rule, lanelet), lanelet.id, rule)
    # An all-way stop lists its lanelets and their stop lines itself; a map need not also reference
    # the rule from each lanelet, and such lines must not be lost.
    for rule in sorted(lmap.regulatoryElementLayer, key=lambda r: r.id):
        if isinstance(rule, ll2.AllWayStop):
            for ll, line in zip(rule.lanelets(), rule.stopLines(), strict=False):
                if (lid := _directed_id(ll)) in lanelets:
                    add(line, lid, rule)
    for rule in sorted(lmap.regulatoryElementLayer, key=lambda r: r.id):
        if not isinstance(rule, ll2.AllWayStop):
            continue
        entries = tuple(lid for ll in rule.lanelets() if (lid := _directed_id(ll)) in lanelets)
        inner = {s for e in entries for s in successors.get(e, ())}
        if not inner:
            raise MapError(f"all-way stop {rule.id}: expected lanelets leaving its entries, got none")
        pts = np.vstack([lanelets[i].polygon() for i in sorted(inner)])
        hull = pts[ConvexHull(pts).vertices]
        stops.append(
            AllWayStop(
                id=rule.id,
                entry_lanelet_ids=entries,
                stop_line_ids=tuple(sl.id for sl in lines.values() if sl.all_way_stop_id == rule.id),
                conflict_polygon=hull,
            )
        )
    return tuple(lines.values()), tuple(stops)


def _signals(lmap: Any, stop_lines: tuple[StopLine, ...]) -> tuple[TrafficSignal, ...]:
    """Traffic-light rules with their heads and bulbs (Autoware ``light_bulbs`` tagged by head id).

    A head's lenses face the traffic it controls: of the two normals of its line string, the one
    towards its stop line.

    Raises:
        MapError: a rule without a stop line or heads, or a head with a ``height`` that is not positive
            (a head without the tag is taken as DEFAULT_HEAD_HEIGHT_M high, Lanelet2 leaves it optional).
    """
    bulbs: dict[int, list[tuple[float, float, float, str]]] = {}
    for ls in lmap.lineStringLayer:
        if _attr(ls.attributes, "type", "") == "light_bulbs" and "traffic_light_id" in ls.attributes:
            owner = int(str(ls.attributes["traffic_light_id"]))
            bulbs.setdefault(owner, []).extend((p.x, p.y, p.z, _attr(p.attributes, "color", "")) for p in ls)
    by_id = {sl.id: sl for sl in stop_lines}
    out = []
    for rule in sorted(lmap.regulatoryElementLayer, key=lambda r: r.id):
        if not isinstance(rule, ll2.TrafficLight):
            continue
        heads_ls = [h for h in rule.trafficLights if isinstance(h, ll2.LineString3d | ll2.ConstLineString3d)]
        if rule.stopLine is None or not heads_ls:
            raise MapError(
                f"traffic light {rule.id}: expected a stop line and at least one head, got stop line "
                f"{rule.stopLine is not None} and {len(heads_ls)} heads"
            )
        line = by_id.get(rule.stopLine.id)
        if line is None:
            continue  # the rule controls no lanelet the map kept: nothing on the road obeys it
        mid = line.line.mean(axis=0)
        heads: list[MapTrafficLight] = []
        bxyz: list[tuple[float, float, float]] = []
        bcol: list[str] = []
        bhead: list[str] = []
        for ls in heads_ls:
            height = float(_attr(ls.attributes, "height", f"{DEFAULT_HEAD_HEIGHT_M:g}"))
            if not height > 0:
                raise MapError(f"traffic light head {ls.id}: expected a positive height, got {height}")
            xy = _xy(ls)
            centre = xy.mean(axis=0)
            along = xy[-1] - xy[0]
            normal = np.array([-along[1], along[0]])
            if float(normal @ (mid - centre)) < 0:
                normal = -normal
            head_id = str(ls.id)
            heads.append(
                MapTrafficLight(
                    light_id=head_id,
                    x_m=float(centre[0]),
                    y_m=float(centre[1]),
                    z_m=float(ls[0].z) + height / 2,
                    facing_rad=math.atan2(normal[1], normal[0]),
                    width_m=float(np.hypot(*along)),
                    height_m=height,
                    signal_id=rule.id,
                    stop_line_id=line.id,
                    stop_x_m=float(mid[0]),
                    stop_y_m=float(mid[1]),
                )
            )
            for x, y, z, colour in bulbs.get(ls.id, []):
                bxyz.append((x, y, z))
                bcol.append(colour)
                bhead.append(head_id)
        out.append(
            TrafficSignal(
                id=rule.id,
                name=_attr(rule.attributes, "name", ""),
                stop_line_id=line.id,
                lanelet_id=line.lanelet_id,
                heads=tuple(heads),
                bulb_xyz_m=np.array(bxyz, dtype=float).reshape(-1, 3),
                bulb_colours=tuple(bcol),
                bulb_head_ids=tuple(bhead),
            )
        )
    return tuple(out)


def is_stop_sign_rule(rule: Any) -> bool:
    """A Lanelet2 ``traffic_sign`` rule whose sign is a stop sign (``STOP_SIGN_TYPES``)."""
    if not isinstance(rule, ll2.TrafficSign) or isinstance(rule, ll2.SpeedLimit):
        return False
    return str(rule.type()).strip().lower() in STOP_SIGN_TYPES


def _stop_line_of(rule: Any, lanelet: Any) -> Any | None:
    if isinstance(rule, ll2.AllWayStop):
        for ll, line in zip(rule.lanelets(), rule.stopLines(), strict=False):
            if ll.id == lanelet.id:
                return line
        return None
    if isinstance(rule, ll2.TrafficLight):
        return rule.stopLine
    if is_stop_sign_rule(rule):
        # A two-way stop: the sign's ref_line is where the shuttle must stand (the sign itself when
        # the map draws no line is not guessed at: the map check lists such a sign as controlling none).
        ref_lines = rule.refLines()
        return ref_lines[0] if len(ref_lines) > 0 else None
    if isinstance(rule, ll2.RightOfWay):
        # The line is where the yielding lanelets stop; the lanelets with right of way drive through.
        yielding = any(ll.id == lanelet.id for ll in rule.yieldLanelets())
        return rule.stopLine if yielding else None
    return None


def _landmarks(lmap: Any) -> tuple[Landmark, ...]:
    """Light poles (points), building facades (the walls of building areas) and traffic signs."""
    out: list[Landmark] = []
    for p in sorted(lmap.pointLayer, key=lambda p: p.id):
        if _attr(p.attributes, "type", "") == "pole":
            sub = _attr(p.attributes, "subtype", "")
            out.append(
                Landmark(id=p.id, kind="light_pole", xy=np.array([[p.x, p.y]]), height_m=p.z, subtype=sub)
            )
    for area in sorted(lmap.areaLayer, key=lambda a: a.id):
        if _attr(area.attributes, "subtype", "") != "building":
            continue
        height = float(_attr(area.attributes, "height", "0"))
        for wall in area.outerBound:
            out.append(Landmark(id=wall.id, kind="building_facade", xy=_xy(wall), height_m=height))
    for ls in sorted(lmap.lineStringLayer, key=lambda ls: ls.id):
        if _attr(ls.attributes, "type", "") == "traffic_sign":
            sub = _attr(ls.attributes, "subtype", "")
            out.append(Landmark(id=ls.id, kind="sign", xy=_xy(ls), height_m=float(ls[0].z), subtype=sub))
    return tuple(out)
