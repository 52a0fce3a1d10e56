"""Map projections: UTM about an origin, Autoware's MGRS grid, and local metric coordinates.

A Lanelet2 OSM file stores latitude/longitude; Autoware-format maps also store the metric position of
every node in ``local_x``/``local_y`` tags, relative to the south-west corner of one 100 km MGRS grid
square (named in ``map_projector_info.yaml``). ``MapProjection`` says which of these the map frame is,
and turns latitude/longitude (stops, recorded waypoints) into that frame.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from pyproj import Transformer

from lastmile.core.errors import ConfigError, MapError
from lastmile.core.geometry import FloatArray

PROJECTOR_INFO_FILE = "map_projector_info.yaml"
_MGRS_COLUMNS = ("ABCDEFGH", "JKLMNPQR", "STUVWXYZ")  # 100 km columns, by (zone - 1) % 3
_MGRS_ROWS = "ABCDEFGHJKLMNPQRSTUV"  # 100 km rows, cycling every 2000 km
_MGRS_BANDS = "CDEFGHJKLMNPQRSTUVWX"  # 8 degree latitude bands from 80 S (X spans 12 degrees)


class ProjectionKind(enum.Enum):
    """How the map frame relates to the Earth."""

    UTM = "utm"  # Lanelet2's UtmProjector: UTM metres minus those of an origin given in degrees
    MGRS = "mgrs"  # Autoware: UTM metres minus the south-west corner of a 100 km MGRS grid square
    LOCAL = "local"  # metric ``local_x``/``local_y`` node tags taken as they are; no geographic frame


@dataclass(frozen=True, kw_only=True)  # no slots: the transformer is cached on the instance
class MapProjection:
    """One projection of a map.

    Attributes:
        kind: UTM, MGRS or LOCAL.
        origin_lat_deg, origin_lon_deg: the UTM origin (UTM only).
        mgrs_grid: the 100 km grid square, such as "44QKE" (MGRS only).
    """

    kind: ProjectionKind
    origin_lat_deg: float = math.nan
    origin_lon_deg: float = math.nan
    mgrs_grid: str = ""

    def __post_init__(self) -> None:
        if self.kind is ProjectionKind.UTM:
            for label, value, bound in (
                ("latitude", self.origin_lat_deg, 90.0),
                ("longitude", self.origin_lon_deg, 180.0),
            ):
                if not (math.isfinite(value) and abs(value) <= bound):
                    raise MapError(
                        f"map origin {label}: expected a number within +-{bound:g} degrees, got {value}"
                    )
        elif self.kind is ProjectionKind.MGRS:
            object.__setattr__(self, "mgrs_grid", self.mgrs_grid.strip().upper())
            _ = mgrs_square_origin(self.mgrs_grid)  # validates the grid name

    @property
    def geographic(self) -> bool:
        """True when latitude/longitude can be turned into map coordinates."""
        return self.kind is not ProjectionKind.LOCAL

    def describe(self) -> str:
        if self.kind is ProjectionKind.UTM:
            return f"UTM about {self.origin_lat_deg:g}, {self.origin_lon_deg:g}"
        if self.kind is ProjectionKind.MGRS:
            return f"MGRS grid {self.mgrs_grid}"
        return "local metric coordinates (local_x/local_y)"

    @cached_property
    def _to_utm(self) -> tuple[Transformer, float, float]:
        """WGS84 -> this projection's UTM zone, and the easting/northing its map frame starts at."""
        if self.kind is ProjectionKind.UTM:
            zone = utm_zone(self.origin_lon_deg)
            north = self.origin_lat_deg >= 0
            tf = _utm_transformer(zone, north)
            e0, n0 = tf.transform(self.origin_lon_deg, self.origin_lat_deg)
            return tf, float(e0), float(n0)
        if self.kind is ProjectionKind.MGRS:
            zone, north, e0, n0 = mgrs_square_origin(self.mgrs_grid)
            return _utm_transformer(zone, north), e0, n0
        raise ConfigError(
            "stop or waypoint position: expected x/y metres on a map in local coordinates, got "
            "latitude/longitude (a local map has no geographic frame; give x_m/y_m)"
        )

    def xy_from_latlon(self, lat_deg: FloatArray, lon_deg: FloatArray) -> FloatArray:
        """(N, 2) map-frame metres of (N,) latitudes and longitudes (degrees).

        For UTM this is Lanelet2's UtmProjector (UTM of the point minus UTM of the origin, the
        origin's zone throughout), so it agrees with the coordinates the map was loaded in.
        """
        lat = np.atleast_1d(np.asarray(lat_deg, dtype=float))
        lon = np.atleast_1d(np.asarray(lon_deg, dtype=float))
        bad = ~(np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ConfigError(
                f"position {k}: expected latitude within +-90 and longitude within +-180 degrees, "
                f"got {lat[k]}, {lon[k]}"
            )
        tf, e0, n0 = self._to_utm
        east, north = tf.transform(lon, lat)
        return np.column_stack([np.asarray(east) - e0, np.asarray(north) - n0])

    def latlon_from_xy(self, xy_m: FloatArray) -> FloatArray:
        """(N, 2) latitude, longitude (degrees) of (N, 2) map-frame metres; the inverse of xy_from_latlon."""
        xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
        tf, e0, n0 = self._to_utm
        lon, lat = tf.transform(xy[:, 0] + e0, xy[:, 1] + n0, direction="INVERSE")
        return np.column_stack([np.asarray(lat), np.asarray(lon)])


def utm_zone(lon_deg: float) -> int:
    """The UTM zone (1-60) of a longitude, as Lanelet2's UtmProjector picks it (no Norway exceptions)."""
    return int(min(max(math.floor((lon_deg + 180.0) / 6.0) + 1, 1), 60))


def _utm_transformer(zone: int, north: bool) -> Transformer:
    epsg = (32600 if north else 32700) + zone
    return Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)


def mgrs_square_origin(grid: str) -> tuple[int, bool, float, float]:
    """Zone, hemisphere, and UTM easting/northing (m) of the south-west corner of an MGRS 100 km square.

    ``grid`` is the zone number, the latitude band and the two square letters, such as "44QKE". The
    row letters repeat every 2000 km of northing; the band says which repetition is meant.

    Raises:
        MapError: the name is not of that form.
    """
    g = grid.strip().upper()
    digits = len(g) - 3
    ok = 1 <= digits <= 2 and g[:digits].isdigit() and 1 <= int(g[:digits]) <= 60
    if ok:
        zone, band, col, row = int(g[:digits]), g[digits], g[digits + 1], g[digits + 2]
        columns = _MGRS_COLUMNS[(zone - 1) % 3]
        ok = band in _MGRS_BANDS and col in columns and row in _MGRS_ROWS
    if not ok:
        raise MapError(
            "MGRS grid: expected a zone, a latitude band and two square letters such as '44QKE', "
            f"got {grid!r}"
        )
    easting = (columns.index(col) + 1) * 100_000.0
    # Even zones start their row letters five squares on (the MGRS-New lettering Autoware uses).
    row_m = ((_MGRS_ROWS.index(row) - (5 if zone % 2 == 0 else 0)) % 20) * 100_000.0
    north = band >= "N"
    band_lo_deg = -80.0 + 8.0 * _MGRS_BANDS.index(band)
    band_hi_deg = 84.0 if band == "X" else band_lo_deg + 8.0
    tf = _utm_transformer(zone, north)
    central_lon = -183.0 + 6.0 * zone
    for k in range(6):
        northing = row_m + 2_000_000.0 * k
        _, lat = tf.transform(easting + 50_000.0, northing + 50_000.0, direction="INVERSE")
        if band_lo_deg - 1.0 <= lat <= band_hi_deg + 1.0:
            return zone, north, easting, northing
    raise MapError(
        f"MGRS grid {grid!r}: expected square {col}{row} to lie in band {band} "
        f"({band_lo_deg:g} to {band_hi_deg:g} deg near longitude {central_lon:g}), it does not"
    )


def read_projector_info(path: str | Path) -> MapProjection:
    """Read Autoware's ``map_projector_info.yaml`` (projector_type MGRS, LocalCartesianUTM or Local).

    Raises:
        MapError: the file is missing, is not YAML, or names a projector this loader does not handle.
    """
    import yaml  # only Autoware maps need it

    p = Path(path)
    if not p.is_file():
        raise MapError(
            f"projector info {str(p)!r}: expected Autoware's {PROJECTOR_INFO_FILE}, got no such file"
        )
    try:
        info = yaml.safe_load(p.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise MapError(f"projector info {str(p)!r}: expected YAML, got: {exc}".splitlines()[0]) from exc
    if not isinstance(info, dict) or "projector_type" not in info:
        raise MapError(f"projector info {str(p)!r}: expected a 'projector_type' key, got {info!r}")
    kind = str(info["projector_type"])
    if kind == "MGRS":
        if "mgrs_grid" not in info:
            raise MapError(f"projector info {str(p)!r}: expected 'mgrs_grid' for an MGRS projector, got none")
        return MapProjection(kind=ProjectionKind.MGRS, mgrs_grid=str(info["mgrs_grid"]))
    if kind == "LocalCartesianUTM":
        origin = info.get("map_origin")
        if not isinstance(origin, dict) or "latitude" not in origin or "longitude" not in origin:
            raise MapError(
                f"projector info {str(p)!r}: expected map_origin latitude/longitude for "
                f"LocalCartesianUTM, got {origin!r}"
            )
        return MapProjection(
            kind=ProjectionKind.UTM,
            origin_lat_deg=float(origin["latitude"]),
            origin_lon_deg=float(origin["longitude"]),
        )
    if kind == "Local":
        return MapProjection(kind=ProjectionKind.LOCAL)
    raise MapError(
        f"projector info {str(p)!r}: expected projector_type MGRS, LocalCartesianUTM or Local, got {kind!r}"
    )


def parse_projector(spec: str, map_path: str | Path) -> MapProjection:
    """A projection from a command-line spec: "utm:LAT,LON", "mgrs:44QKE", "mgrs" / "autoware" (read
    ``map_projector_info.yaml`` beside the map) or "local".

    Raises:
        ConfigError: the spec is none of these.
    """
    kind, _, arg = spec.strip().partition(":")
    kind = kind.lower()
    if kind == "utm":
        parts = arg.split(",")
        try:
            lat, lon = (float(v) for v in parts)
        except ValueError:
            raise ConfigError(f"--projector utm: expected 'utm:LAT,LON' in degrees, got {spec!r}") from None
        return MapProjection(kind=ProjectionKind.UTM, origin_lat_deg=lat, origin_lon_deg=lon)
    if kind == "mgrs" and arg:
        return MapProjection(kind=ProjectionKind.MGRS, mgrs_grid=arg)
    if kind in ("mgrs", "autoware") and not arg:
        return read_projector_info(Path(map_path).with_name(PROJECTOR_INFO_FILE))
    if kind == "local" and not arg:
        return MapProjection(kind=ProjectionKind.LOCAL)
    raise ConfigError(
        f"--projector: expected 'utm:LAT,LON', 'mgrs:GRID', 'mgrs' (read {PROJECTOR_INFO_FILE}) or 'local', "
        f"got {spec!r}"
    )
