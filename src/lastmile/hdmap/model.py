"""The typed map the stack and the simulator use, independent of the file format it came from.

The Lanelet2 loader that fills it (and the built-in campus map generator) arrive with issue #2's
hdmap work; this module fixes the shape every consumer codes against.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import MapError
from lastmile.core.geometry import FloatArray, point_in_polygon
from lastmile.core.polyline import Polyline


@dataclass(frozen=True, slots=True, kw_only=True)
class LaneletInfo:
    """One lanelet: bounds and centre line in its driving direction.

    Attributes:
        subtype: Lanelet2 subtype ("road", "crosswalk", "parking", ...).
        left_type, right_type: boundary types ("curbstone", "line_thin", ...).
        turn: "" or "left" / "right" / "straight" inside intersections.
        bus_stop_id: the stop whose bay this lanelet is ("" for ordinary lanes).
    """

    id: int
    centerline: Polyline
    left: Polyline
    right: Polyline
    speed_limit_mps: float
    subtype: str = "road"
    left_type: str = ""
    right_type: str = ""
    turn: str = ""
    bus_stop_id: str = ""

    def polygon(self) -> FloatArray:
        """(N, 2) outline: the left bound forward, the right bound back."""
        return np.vstack([self.left.xy_m, self.right.xy_m[::-1]])


@dataclass(frozen=True, slots=True, kw_only=True)
class BusStop:
    """A stop with a pull-in bay; ``curb`` runs along the platform in the driving direction."""

    id: str
    name: str
    lane_lanelet_id: int
    bay_lanelet_id: int
    curb: Polyline

    @property
    def length_m(self) -> float:
        return self.curb.length_m


@dataclass(frozen=True, slots=True, kw_only=True)
class Crosswalk:
    """A marked crossing; ``polygon`` (N, 2) covers the whole road width."""

    id: int
    polygon: FloatArray
    width_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class StopLine:
    """A stop line at the end of ``lanelet_id``; ``line`` is (2, 2)."""

    id: int
    line: FloatArray
    lanelet_id: int
    all_way_stop_id: int | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class AllWayStop:
    """An all-way stop: its entries and the box where their paths conflict ((N, 2) polygon)."""

    id: int
    entry_lanelet_ids: tuple[int, ...]
    stop_line_ids: tuple[int, ...]
    conflict_polygon: FloatArray


@dataclass(frozen=True, slots=True, kw_only=True)
class Landmark:
    """A mapped landmark for GNSS-denied localization: "light_pole", "building_facade" or "sign"."""

    id: int
    kind: str
    xy: FloatArray
    height_m: float
    subtype: str = ""


@dataclass(frozen=True, kw_only=True)
class HDMap:
    """A road map: lanelets and the features a shuttle service needs."""

    name: str
    lanelets: Mapping[int, LaneletInfo]
    successor_ids: Mapping[int, tuple[int, ...]]
    stops: tuple[BusStop, ...] = ()
    crosswalks: tuple[Crosswalk, ...] = ()
    stop_lines: tuple[StopLine, ...] = ()
    all_way_stops: tuple[AllWayStop, ...] = ()
    landmarks: tuple[Landmark, ...] = ()
    curbs: tuple[Polyline, ...] = ()
    _polygons: dict[int, tuple[FloatArray, FloatArray, FloatArray]] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not self.lanelets:
            raise MapError(f"HDMap {self.name!r}: expected at least one lanelet, got none")
        for lid, succ in self.successor_ids.items():
            missing = [s for s in succ if s not in self.lanelets]
            if lid not in self.lanelets or missing:
                raise MapError(
                    f"HDMap {self.name!r}: successor table names unknown lanelets {[lid, *missing]}"
                )
        for lid, ll in self.lanelets.items():
            poly = ll.polygon()
            self._polygons[lid] = (poly, poly.min(axis=0), poly.max(axis=0))

    def successors(self, lanelet_id: int) -> tuple[int, ...]:
        return tuple(self.successor_ids.get(lanelet_id, ()))

    def lanelet_at(self, x_m: float, y_m: float) -> int | None:
        """A lanelet whose outline contains the point (drivable ones before crosswalks), else None."""
        found: int | None = None
        for lid, (poly, lo, hi) in self._polygons.items():
            if lo[0] <= x_m <= hi[0] and lo[1] <= y_m <= hi[1] and point_in_polygon(x_m, y_m, poly):
                if self.lanelets[lid].subtype != "crosswalk":
                    return lid
                found = lid
        return found

    def is_drivable(self, xy_m: FloatArray) -> np.ndarray:
        """(N,) bool: which of the (N, 2) points lie on a lanelet other than a crosswalk."""
        pts = np.asarray(xy_m, dtype=float).reshape(-1, 2)
        out = np.zeros(len(pts), dtype=bool)
        for i, (x, y) in enumerate(pts.tolist()):
            lid = self.lanelet_at(x, y)
            out[i] = lid is not None and self.lanelets[lid].subtype != "crosswalk"
        return out

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        lo = np.min([p[1] for p in self._polygons.values()], axis=0)
        hi = np.max([p[2] for p in self._polygons.values()], axis=0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])
