"""``lastmile map check``: what a map offers a shuttle service, what is missing, and what that turns off.

Each layer the stack reads from a map is counted over the whole map and, given a route, along the
service path (the s-layer database); a missing layer names the feature that will be off.
"""

from __future__ import annotations

import collections
import enum
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.core.errors import ConfigError, LastmileError
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_projected_map
from lastmile.hdmap.model import DRIVABLE_SUBTYPES, HDMap, SignRule
from lastmile.hdmap.projection import PROJECTOR_INFO_FILE, MapProjection, parse_projector, read_projector_info
from lastmile.hdmap.route_file import MAX_SNAP_M, read_route_file
from lastmile.hdmap.service_route import ServiceRoute, build_service, find_gaps


class Status(enum.Enum):
    OK = "ok"
    MISSING = "missing"
    ERROR = "error"


@dataclass(frozen=True, slots=True, kw_only=True)
class CheckItem:
    """One layer: what the map has, and (when missing) the feature that will be off."""

    layer: str
    status: Status
    detail: str
    off: str = ""


@dataclass(frozen=True, slots=True, kw_only=True)
class MapCheck:
    """The report: the map, the service route if one was given, its s-layers, and one item per layer."""

    hdmap: HDMap
    projection: MapProjection
    route: ServiceRoute | None
    layers: SLayerDatabase | None
    items: tuple[CheckItem, ...]

    @property
    def has_errors(self) -> bool:
        return any(i.status is Status.ERROR for i in self.items)


def projection_for(map_path: Path, projector: str | None) -> MapProjection:
    """The projection a ``--projector`` spec names, else Autoware's file beside the map.

    Raises:
        ConfigError: no spec and no ``map_projector_info.yaml`` beside the map.
    """
    if projector:
        return parse_projector(projector, map_path)
    beside = map_path.with_name(PROJECTOR_INFO_FILE)
    if beside.is_file():
        return read_projector_info(beside)
    raise ConfigError(
        f"map {str(map_path)!r}: expected --projector (utm:LAT,LON, mgrs:GRID or local) or a "
        f"{PROJECTOR_INFO_FILE} beside the map, got neither"
    )


def check(map_path: Path | None, projector: str | None, route_path: Path | None) -> MapCheck:
    """Load the map (and the route) and judge every layer.

    Raises:
        LastmileError: the map or the route file cannot be read (malformed OSM, a wrong projection,
            no lanelets, a bad route file). Problems of the route on a readable map (a stop too far
            from the lanes, no way between stops, no speed limit) are reported as error items.
    """
    if route_path is not None:
        spec = read_route_file(route_path)
        if map_path is not None and map_path.resolve() != spec.map_path.resolve():
            raise ConfigError(
                f"map check: expected the map the route file names ({spec.map_path}), got {map_path}"
            )
        projection = parse_projector(projector, spec.map_path) if projector else spec.projection
        hdmap = load_projected_map(spec.map_path, projection)
    else:
        if map_path is None:
            raise ConfigError("map check: expected a map file or --route, got neither")
        projection = projection_for(map_path, projector)
        hdmap = load_projected_map(map_path, projection)
        spec = None
    items: list[CheckItem] = [_lanelets(hdmap)]
    route: ServiceRoute | None = None
    db: SLayerDatabase | None = None
    if spec is not None:
        try:
            route = build_service(spec, hdmap)
        except LastmileError as exc:
            items.append(CheckItem(layer="route", status=Status.ERROR, detail=str(exc)))
    if route is not None:
        items.append(_route(route))
        items.append(kerbside_item(route))
        try:
            db = route.layers()
        except LastmileError as exc:
            items.append(CheckItem(layer="s-layers", status=Status.ERROR, detail=str(exc)))
    elif spec is None:
        items.append(
            CheckItem(
                layer="route",
                status=Status.MISSING,
                detail=f"no route file given; the largest closed drivable circuit: {_largest_circuit(hdmap)}",
                off="the service loop: give --route ROUTE.toml to check the loop through your stops",
            )
        )
    items += [
        _speed(hdmap, route, db),
        _rules(hdmap, db),
        _signs(hdmap, db),
        _curbs(hdmap, db),
        _landmarks(hdmap, db),
        _stops(hdmap),
        _buildings(hdmap),
    ]
    return MapCheck(hdmap=hdmap, projection=projection, route=route, layers=db, items=tuple(items))


def _drivable(hdmap: HDMap) -> list[int]:
    return [k for k, v in hdmap.lanelets.items() if v.subtype in DRIVABLE_SUBTYPES]


def _lanelets(hdmap: HDMap) -> CheckItem:
    drv = _drivable(hdmap)
    km = sum(hdmap.lanelets[k].centerline.length_m for k in drv if k > 0) / 1000.0
    if not drv:
        return CheckItem(layer="lanelets", status=Status.ERROR, detail="no drivable lanelet (road, bus_lane)")
    lane_change = sum(1 for k in drv if hdmap.neighbours(k))
    return CheckItem(
        layer="lanelets",
        status=Status.OK,
        detail=f"{len(hdmap.lanelets)} directed lanelets, {len(drv)} drivable ({km:.2f} km of lane), "
        f"{lane_change} with a permitted lane change",
    )


def _largest_circuit(hdmap: HDMap) -> str:
    """The largest set of drivable lanelets that all reach each other (successors and lane changes)."""
    drv = set(_drivable(hdmap))
    adj = {k: [n for n in (*hdmap.successors(k), *hdmap.neighbours(k)) if n in drv] for k in drv}
    circuits = [c for c in _strong_components(adj) if len(c) > 1 or c[0] in adj[c[0]]]
    gaps = find_gaps(hdmap, 2 * MAX_SNAP_M)
    hint = (
        f"; {len(gaps)} dead ends lie within {2 * MAX_SNAP_M:g} m of a lane start heading the same way "
        f"(route files bridge them with map.connect_gaps_m, smallest {min(g for _, _, g in gaps):.1f} m)"
        if gaps
        else ""
    )
    if not circuits:
        return "none (no set of lanelets that reach each other)" + hint
    best = max(circuits, key=len)
    metres = sum(hdmap.lanelets[k].centerline.length_m for k in best)
    return f"{len(best)} lanelets, {metres:.0f} m of lane" + hint


def _strong_components(adj: dict[int, list[int]]) -> list[list[int]]:
    """Tarjan's algorithm, iterative (maps have thousands of lanelets; no recursion limit to hit)."""
    index: dict[int, int] = {}
    low: dict[int, int] = {}
    stack: list[int] = []
    on_stack: set[int] = set()
    out: list[list[int]] = []
    counter = 0
    for root in adj:
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            v, i = work.pop()
            if i == 0:
                index[v] = low[v] = counter
                counter += 1
                stack.append(v)
                on_stack.add(v)
            recurse = False
            for j in range(i, len(adj[v])):
                w = adj[v][j]
                if w not in index:
                    work.append((v, j + 1))
                    work.append((w, 0))
                    recurse = True
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            if recurse:
                continue
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                out.append(comp)
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[v])
    return out


def _route(route: ServiceRoute) -> CheckItem:
    changes = sum(
        1
        for a, b in zip(route.lanelet_ids, (*route.lanelet_ids[1:], route.lanelet_ids[0]), strict=True)
        if b not in route.hdmap.successors(a)
    )
    far = max(s.snap.distance_m for s in route.stops)
    pattern = route.spec.pattern.value if route.spec else "loop"
    stops = ", ".join(f"{s.name} @ {s.route_s_m:.0f} m (snap {s.snap.distance_m:.1f} m)" for s in route.stops)
    gaps = "".join(f"; bridged a {g:.1f} m gap {a} -> {b}" for a, b, g in route.bridged_gaps)
    return CheckItem(
        layer="route",
        status=Status.OK,
        detail=f"{pattern} of {route.length_m:.0f} m through {len(route.stops)} stops over "
        f"{len(route.lanelet_ids)} lanelets, {changes} lane changes, {len(route.junctions)} branches/merges "
        f"at {len(route.intersections())} places; farthest snap {far:.1f} m{gaps}. Stops: {stops}",
    )


def kerbside_lines(route: ServiceRoute) -> list[str]:
    """One line per kerbside stop the route build moved off a bend (``service_route._dockable``), or
    could not: where the straight body kept off the kerb leaves the door farther from it than the
    route's ``max_door_gap_m``."""
    if route.spec is None:
        return []
    limit = route.spec.max_door_gap_m
    out = []
    for st in route.stops:
        if st.door_gap_m is None or st.door_gap_given_m is None:
            continue
        if st.door_gap_m != st.door_gap_given_m and st.door_gap_m <= limit:
            out.append(
                f"{st.name}: moved {st.moved_m:+.1f} m along its lane off a bend (the door "
                f"{st.door_gap_given_m:.2f} m from the kerb where given, {st.door_gap_m:.2f} m where moved)"
            )
        elif st.door_gap_m > limit:
            out.append(
                f"{st.name}: the door will be {st.door_gap_m:.2f} m from the kerb (over {limit:.2f} m): no "
                f"place within {route.spec.max_stop_move_m:.0f} m of it is straight enough"
            )
    return out


def kerbside_item(route: ServiceRoute) -> CheckItem:
    lines = kerbside_lines(route)
    unmet = [ln for ln in lines if "will be" in ln]
    kerbside = sum(1 for st in route.stops if st.door_gap_m is not None)
    detail = f"{kerbside} kerbside stops, door within {route.spec.max_door_gap_m if route.spec else 0:.2f} m"
    detail += "".join(f"; {ln}" for ln in lines)
    if unmet:
        return CheckItem(
            layer="kerbside stops",
            status=Status.MISSING,
            detail=detail,
            off="the curb-gap target at those stops: move them in the route file to a straighter kerb",
        )
    return CheckItem(layer="kerbside stops", status=Status.OK, detail=detail)


def _speed(hdmap: HDMap, route: ServiceRoute | None, db: SLayerDatabase | None) -> CheckItem:
    drv = _drivable(hdmap)
    mapped = sum(1 for k in drv if math.isfinite(hdmap.lanelets[k].speed_limit_mps))
    detail = f"{mapped} of {len(drv)} drivable lanelets carry a speed limit"
    if db is not None:
        kph = np.unique(np.round(db.speed_limit_mps * 3.6, 1)).tolist()
        detail += f"; along the route {kph} km/h"
    if mapped == len(drv):
        return CheckItem(layer="speed limits", status=Status.OK, detail=detail)
    fallback = None if route is None else route.unmapped_speed_limit_mps
    if fallback is not None:
        detail += f"; the route file's {fallback * 3.6:.0f} km/h applies to the others"
        return CheckItem(layer="speed limits", status=Status.MISSING, detail=detail, off="")
    return CheckItem(
        layer="speed limits",
        status=Status.MISSING,
        detail=detail + " (no country default is assumed)",
        off="a service on unmapped lanelets: set map.unmapped_speed_limit_kph in the route file",
    )


def _rules(hdmap: HDMap, db: SLayerDatabase | None) -> CheckItem:
    counts = (
        f"{len(hdmap.all_way_stops)} all-way stops, {len(hdmap.signals)} traffic lights "
        f"({len(hdmap.traffic_lights)} heads), {len(hdmap.crosswalks)} crosswalks, "
        f"{len(hdmap.stop_lines)} stop lines"
    )
    if hdmap.unread_rules:
        counts += "; not read (Lanelet2 has no class for them): " + ", ".join(
            f"{name} x{n}" for name, n in hdmap.unread_rules
        )
    if db is not None:
        counts += (
            f"; along the route {len(db.stop_lines)} stop lines ({len(db.signal_stop_lines)} signalised), "
            f"{len(db.crosswalks)} crosswalks"
        )
    if hdmap.all_way_stops or hdmap.signals or hdmap.crosswalks:
        return CheckItem(layer="regulatory elements", status=Status.OK, detail=counts)
    return CheckItem(
        layer="regulatory elements",
        status=Status.MISSING,
        detail=counts,
        off="all-way-stop, traffic-light and crosswalk behaviour and their referee checks (nothing mapped "
        "to obey: unmapped junctions and crossings are not known to the stack)",
    )


def _signs(hdmap: HDMap, db: SLayerDatabase | None) -> CheckItem:
    """The traffic signs drawn (by type) and the stop lines a stop sign's rule controls."""
    kinds = collections.Counter(lm.subtype or "untyped" for lm in hdmap.landmarks if lm.kind == "sign")
    drawn = ", ".join(f"{k} x{n}" for k, n in sorted(kinds.items())) or "none"
    controlled = [
        f"rule {sl.stop_sign_id}: line {sl.id} at the end of lanelet {sl.lanelet_id} "
        + ("(all-way stop)" if sl.all_way_stop_id is not None else "(two-way stop: full stop, then on)")
        for sl in hdmap.stop_lines
        if sl.stop_sign_id is not None
    ]
    detail = f"{sum(kinds.values())} drawn ({drawn}); {len(controlled)} stop-sign stop lines"
    if controlled:
        detail += ": " + "; ".join(controlled)
    limits = [_speed_rule(hdmap, r) for r in hdmap.sign_rules if r.speed_limit]
    if limits:
        detail += f"; {len(limits)} speed-limit rules: " + "; ".join(limits)
    if db is not None:
        along = sum(1 for rl in db.stop_lines if rl.stop_line.stop_sign_id is not None)
        detail += f"; along the route {along} stop-sign lines"
    if controlled:
        return CheckItem(layer="traffic signs", status=Status.OK, detail=detail)
    return CheckItem(
        layer="traffic signs",
        status=Status.MISSING,
        detail=detail,
        off="stop signs as virtual stop lines (a traffic_sign rule of a de206 / us:R1-1 sign with a "
        "ref_line) and their referee check; speed-limit signs act through speed_limit rules (see above)",
    )


def _speed_rule(hdmap: HDMap, rule: SignRule) -> str:
    """One speed-limit rule: its sign and the lanelets it limits (or that it limits none)."""
    if not rule.lanelet_ids:
        return f"rule {rule.id} ({rule.sign_type}) controls no lanelet (none references it)"
    kph = sorted({round(hdmap.lanelets[k].speed_limit_mps * 3.6, 1) for k in rule.lanelet_ids})
    shown = ", ".join(str(k) for k in rule.lanelet_ids[:5]) + (" ..." if len(rule.lanelet_ids) > 5 else "")
    return f"rule {rule.id} ({rule.sign_type}) sets {kph} km/h on {len(rule.lanelet_ids)} lanelets ({shown})"


def _curbs(hdmap: HDMap, db: SLayerDatabase | None) -> CheckItem:
    detail = f"{len(hdmap.curbs)} curb lines (curbstone, road_border)"
    if db is not None:
        share = float(np.isfinite(db.curb_right_d_m).mean()) if len(db.s_m) else 0.0
        detail += f"; a curb beside {share:.0%} of the route"
    if hdmap.curbs and (db is None or np.isfinite(db.curb_right_d_m).any()):
        return CheckItem(layer="curbs", status=Status.OK, detail=detail)
    return CheckItem(
        layer="curbs",
        status=Status.MISSING,
        detail=detail,
        off="the curb-gap pull-over target (stops are made at the lane's right edge), curb steps in the "
        "simulated world, and curbs as landmarks for GNSS-denied localization",
    )


def _landmarks(hdmap: HDMap, db: SLayerDatabase | None) -> CheckItem:
    kinds = {
        k: sum(1 for lm in hdmap.landmarks if lm.kind == k) for k in ("light_pole", "sign", "building_facade")
    }
    detail = f"{kinds['light_pole']} poles, {kinds['sign']} signs, {kinds['building_facade']} building walls"
    if db is not None and len(db.s_m):
        seen = float((np.diff(db.landmark_start) > 0).mean())
        detail += f"; a landmark within 40 m of {seen:.0%} of the route"
    if hdmap.landmarks and (db is None or db.landmark_start[-1] > 0):
        return CheckItem(layer="landmarks", status=Status.OK, detail=detail)
    return CheckItem(
        layer="landmarks",
        status=Status.MISSING,
        detail=detail,
        off="GNSS-denied landmark localization along the route (WATonoBus III-B2), and poles and signs "
        "in the simulated world",
    )


def _stops(hdmap: HDMap) -> CheckItem:
    tagged = len(hdmap.tagged_stops)
    detail = f"{len(hdmap.stops)} bays tagged lastmile:bus_stop, {tagged} tagged stop points"
    if hdmap.stops or tagged:
        return CheckItem(layer="stops in the map", status=Status.OK, detail=detail)
    return CheckItem(
        layer="stops in the map",
        status=Status.MISSING,
        detail=detail,
        off="stops_from = 'map' (list the stops in the route file instead); no mapped bays, so every stop "
        "is kerbside",
    )


def _buildings(hdmap: HDMap) -> CheckItem:
    buildings = sum(1 for a in hdmap.areas if a.subtype == "building")
    if buildings:
        return CheckItem(layer="buildings", status=Status.OK, detail=f"{buildings} building areas")
    return CheckItem(
        layer="buildings",
        status=Status.MISSING,
        detail="0 building areas",
        off="buildings in the simulated world (the LiDAR sees open ground) and facades as landmarks",
    )


def format_report(report: MapCheck) -> str:
    """The report as lines of text: one per layer, and the feature off under each missing one."""
    h = report.hdmap
    x0, y0, x1, y1 = h.bounds_m
    lines = [
        f"map {h.name}: {report.projection.describe()}; extent {x1 - x0:.0f} m x {y1 - y0:.0f} m",
    ]
    for item in report.items:
        lines.append(f"  [{item.status.value:>7}] {item.layer}: {item.detail}")
        if item.off:
            lines.append(f"            off: {item.off}")
    return "\n".join(lines)


def main_check(
    map_path: Path | None, projector: str | None, route_path: Path | None, png_path: Path | None
) -> int:
    """Run the check, print the report, write the PNG; the exit code (1 on errors)."""
    from lastmile.hdmap.map_plot import plot_map_check

    report = check(map_path, projector, route_path)
    print(format_report(report))
    if png_path is not None:
        plot_map_check(report.hdmap, report.route, png_path)
        print(f"wrote {png_path}")
    if report.has_errors:
        print("map check: errors above", file=sys.stderr)
        return 1
    return 0
