"""The route file (TOML): which map, its projection, the stops and the service pattern.

```toml
name = "BITS campus loop"

[map]
path = "../shared/data/maps/campus_shuttle_bits/lanelet2_map.osm"  # the route file's folder, then the cwd
projection = "mgrs"            # "utm" (origin_lat_deg, origin_lon_deg), "mgrs" (mgrs_grid, or Autoware's
                               # map_projector_info.yaml beside the map) or "local" (local_x/local_y tags)
unmapped_speed_limit_kph = 15  # lanelets whose map states no limit; without it they are an error
connect_gaps_m = 5.0           # join a lanelet's end to a lanelet starting this close (default 0: off)

[service]
pattern = "loop"               # "loop" (through the stops in order and back to the first) or "out_and_back"
stops_from = "file"            # "file" ([[stops]] below) or "map" (tagged stops; order = [names])
platform_length_m = 12.0       # kerbside length of a stop without a mapped bay
max_door_gap_m = 0.4           # a kerbside stop where the door cannot come this near the kerb is moved
max_stop_move_m = 12.0         # ... at most this far along its lane (default: one platform length)
waypoints = "drive.csv"        # optional: a GEM-style recorded drive (lat, lon, speed) the path follows

[[stops]]
name = "Main Gate"
x_m = 42302.34                 # map frame; or lat_deg / lon_deg
y_m = 41729.12
heading_deg = 120.0            # optional: the direction of travel at the stop (map frame, CCW from east)
```
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lastmile.core.config import file_candidates, from_mapping, load_toml, resolve_file
from lastmile.core.errors import ConfigError
from lastmile.hdmap.projection import (
    PROJECTOR_INFO_FILE,
    MapProjection,
    ProjectionKind,
    read_projector_info,
)

MAX_SNAP_M = 5.0
"""A stop farther than this from every lanelet is a mistake in the route file, not a kerbside stop
(a lane is 3-3.5 m wide, a platform a step beside it)."""

DEFAULT_PLATFORM_LENGTH_M = 12.0
"""Kerbside length of a stop without a mapped bay: one standard 12 m bus (a shuttle is shorter)."""
DEFAULT_MAX_DOOR_GAP_M = 0.4
"""The door gap a kerbside stop must allow (``curb_fit.rest_door_gap_m``): 0.5 m is the most a served
stop is accepted at (the closed-loop tests' bound), less 0.1 m for the pull-over's own lateral
stopping error; a platform on a bend where the straight body kept off the kerb leaves the door
farther is moved."""


class ServicePattern(enum.Enum):
    LOOP = "loop"  # through the stops in order, then back to the first
    OUT_AND_BACK = "out_and_back"  # through the stops in order, then through them backwards


class StopSource(enum.Enum):
    FILE = "file"
    MAP = "map"


@dataclass(frozen=True, slots=True, kw_only=True)
class StopEntry:
    """One stop as the route file gives it: map-frame x/y, or latitude/longitude."""

    name: str
    x_m: float | None = None
    y_m: float | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    heading_deg: float | None = None

    def __post_init__(self) -> None:
        metric = self.x_m is not None and self.y_m is not None
        geographic = self.lat_deg is not None and self.lon_deg is not None
        partial = [k for k in ("x_m", "y_m", "lat_deg", "lon_deg") if getattr(self, k) is not None]
        if metric == geographic or len(partial) != 2:
            raise ConfigError(
                f"stop {self.name!r}: expected x_m and y_m, or lat_deg and lon_deg, "
                f"got {partial or 'neither'}"
            )
        if not self.name.strip():
            raise ConfigError("stop: expected a non-empty name, got ''")


@dataclass(frozen=True, slots=True, kw_only=True)
class _MapTable:
    path: str
    projection: str = ""
    origin_lat_deg: float | None = None
    origin_lon_deg: float | None = None
    mgrs_grid: str = ""
    unmapped_speed_limit_kph: float | None = None
    connect_gaps_m: float = 0.0


@dataclass(frozen=True, slots=True, kw_only=True)
class _ServiceTable:
    pattern: ServicePattern = ServicePattern.LOOP
    stops_from: StopSource = StopSource.FILE
    order: tuple[str, ...] = ()
    platform_length_m: float = DEFAULT_PLATFORM_LENGTH_M
    max_door_gap_m: float = DEFAULT_MAX_DOOR_GAP_M
    max_stop_move_m: float | None = None
    waypoints: str = ""


@dataclass(frozen=True, slots=True, kw_only=True)
class _RouteTable:
    name: str = ""
    map: _MapTable
    service: _ServiceTable = _ServiceTable()
    stops: tuple[StopEntry, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class RouteSpec:
    """A route file, read and checked (paths resolved, projection built); nothing routed yet.

    Attributes:
        unmapped_speed_limit_mps: limit on lanelets whose map states none (None: those are an error).
        connect_gaps_m: a lanelet's end is joined to a lanelet starting within this distance, in about
            the same heading (0: only Lanelet2's own successors).
        order: with stops from the map, their names in service order (empty: map order).
        max_door_gap_m: a kerbside stop whose door cannot come this near its kerb (a bend the
            straight body cannot lie along) is moved along its lane to where it can.
        max_stop_move_m: how far such a stop may move (default: one platform length, so the door
            stays within reach of a rider waiting anywhere on the given platform); farther, it stays
            and ``lastmile map check`` says what its door gap will be.
        waypoints_path: a GEM-style recorded drive the path follows (None: A* between the stops).
    """

    source: Path
    name: str
    map_path: Path
    projection: MapProjection
    pattern: ServicePattern
    stop_source: StopSource
    stops: tuple[StopEntry, ...]
    order: tuple[str, ...]
    platform_length_m: float
    unmapped_speed_limit_mps: float | None
    connect_gaps_m: float
    waypoints_path: Path | None
    max_door_gap_m: float = DEFAULT_MAX_DOOR_GAP_M
    max_stop_move_m: float = DEFAULT_PLATFORM_LENGTH_M


def read_route_file(path: str | Path) -> RouteSpec:
    """Read and check a route file.

    Raises:
        ConfigError: unknown or missing keys, a missing projection, a map or waypoint file that does
            not exist, stops given twice or not at all.
        MapError: an Autoware projector file that cannot be read.
    """
    source = Path(path)
    raw: dict[str, Any] = load_toml(source)
    table = from_mapping(_RouteTable, raw, str(source))
    m, svc = table.map, table.service
    map_path = _resolve(source, m.path, "map.path")
    projection = _projection(source, m, map_path)
    if m.unmapped_speed_limit_kph is not None and not (0 < m.unmapped_speed_limit_kph <= 130):
        raise ConfigError(
            f"{source}: map.unmapped_speed_limit_kph: expected a limit in (0, 130] km/h, "
            f"got {m.unmapped_speed_limit_kph}"
        )
    if not (0.0 <= m.connect_gaps_m <= 2 * MAX_SNAP_M):
        raise ConfigError(
            f"{source}: map.connect_gaps_m: expected 0 to {2 * MAX_SNAP_M:g} m, got {m.connect_gaps_m}"
        )
    if not (2.0 <= svc.platform_length_m <= 60.0):
        raise ConfigError(
            f"{source}: service.platform_length_m: expected 2 to 60 m, got {svc.platform_length_m}"
        )
    if not (0.0 < svc.max_door_gap_m <= 2.0):
        raise ConfigError(f"{source}: service.max_door_gap_m: expected (0, 2] m, got {svc.max_door_gap_m}")
    move = svc.platform_length_m if svc.max_stop_move_m is None else svc.max_stop_move_m
    if not (0.0 <= move <= 100.0):
        raise ConfigError(f"{source}: service.max_stop_move_m: expected 0 to 100 m, got {move}")
    if svc.stops_from is StopSource.FILE and len(table.stops) < 2:
        raise ConfigError(
            f"{source}: expected at least two [[stops]] (or service.stops_from = 'map'), "
            f"got {len(table.stops)}"
        )
    if svc.stops_from is StopSource.MAP and table.stops:
        raise ConfigError(f"{source}: expected [[stops]] or service.stops_from = 'map', got both")
    names = [s.name for s in table.stops] or list(svc.order)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"{source}: expected each stop named once, got {dup[0]!r} twice")
    if not projection.geographic and any(s.lat_deg is not None for s in table.stops):
        raise ConfigError(
            f"{source}: stops in lat_deg/lon_deg need a geographic projection (utm or mgrs), got 'local'"
        )
    return RouteSpec(
        source=source,
        name=table.name or source.stem,
        map_path=map_path,
        projection=projection,
        pattern=svc.pattern,
        stop_source=svc.stops_from,
        stops=table.stops,
        order=svc.order,
        platform_length_m=svc.platform_length_m,
        unmapped_speed_limit_mps=(
            None if m.unmapped_speed_limit_kph is None else m.unmapped_speed_limit_kph / 3.6
        ),
        connect_gaps_m=m.connect_gaps_m,
        waypoints_path=_resolve(source, svc.waypoints, "service.waypoints") if svc.waypoints else None,
        max_door_gap_m=svc.max_door_gap_m,
        max_stop_move_m=move,
    )


def _resolve(source: Path, given: str, key: str) -> Path:
    """A path as written: absolute, else beside the route file, else from the working directory."""
    found = resolve_file(source, given)
    if found is not None:
        return found
    tried = file_candidates(source, given)
    raise ConfigError(
        f"{source}: {key}: expected a file at {given!r}, got none (looked in {', '.join(map(str, tried))})"
    )


def _projection(source: Path, m: _MapTable, map_path: Path) -> MapProjection:
    kind = m.projection.strip().lower()
    if not kind:
        raise ConfigError(
            f"{source}: map.projection: expected 'utm' (with origin_lat_deg, origin_lon_deg), 'mgrs' or "
            "'local', got none"
        )
    if kind == "utm":
        if m.origin_lat_deg is None or m.origin_lon_deg is None:
            raise ConfigError(f"{source}: map.projection 'utm': expected origin_lat_deg and origin_lon_deg")
        return MapProjection(
            kind=ProjectionKind.UTM, origin_lat_deg=m.origin_lat_deg, origin_lon_deg=m.origin_lon_deg
        )
    extra = [k for k in ("origin_lat_deg", "origin_lon_deg") if getattr(m, k) is not None]
    if extra:
        raise ConfigError(f"{source}: map.{extra[0]}: only a 'utm' projection takes an origin, got {kind!r}")
    if kind == "mgrs":
        if m.mgrs_grid:
            return MapProjection(kind=ProjectionKind.MGRS, mgrs_grid=m.mgrs_grid)
        info = read_projector_info(map_path.with_name(PROJECTOR_INFO_FILE))
        if info.kind is not ProjectionKind.MGRS:
            raise ConfigError(
                f"{source}: map.projection 'mgrs': expected {PROJECTOR_INFO_FILE} to name an MGRS grid, "
                f"got {info.describe()}"
            )
        return info
    if kind == "local":
        return MapProjection(kind=ProjectionKind.LOCAL)
    raise ConfigError(f"{source}: map.projection: expected 'utm', 'mgrs' or 'local', got {m.projection!r}")


def heading_rad(entry: StopEntry) -> float | None:
    return None if entry.heading_deg is None else math.radians(entry.heading_deg)
