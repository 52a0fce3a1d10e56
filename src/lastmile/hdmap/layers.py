"""WATonoBus's s-coordinate layer database: the route cut at equal s, a record per step (Fig. 7)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import MapError
from lastmile.core.polyline import Polyline
from lastmile.hdmap.model import BusStop, Crosswalk, HDMap, StopLine


@dataclass(frozen=True, slots=True, kw_only=True)
class RouteStop:
    """A stop located on the route: platform extent in s, and the curb's signed offset (right < 0)."""

    stop: BusStop
    s_start_m: float
    s_end_m: float
    curb_d_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class RouteCrosswalk:
    crosswalk: Crosswalk
    s_start_m: float
    s_end_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class RouteStopLine:
    stop_line: StopLine
    s_m: float
    all_way_stop_id: int | None


@dataclass(frozen=True, kw_only=True)
class SLayerDatabase:
    """Per-s records along a route.

    Attributes:
        centerline: the route's centre line (closed for a loop).
        s_m: (N,) record positions, equally spaced by ``step_m``.
        speed_limit_mps, lane_left_d_m, lane_right_d_m, curb_right_d_m: (N,) layers; lane and curb
            offsets are signed distances from the centre line, left positive (NaN: no curb nearby).
        road_type: (N,) int8 codes: 0 normal, 1 intersection, 2 crosswalk, 3 bus bay, 4 driveway.
        stops, crosswalks, stop_lines: features located on the route, in s order.
    """

    hdmap: HDMap
    centerline: Polyline
    step_m: float
    s_m: np.ndarray
    speed_limit_mps: np.ndarray
    lane_left_d_m: np.ndarray
    lane_right_d_m: np.ndarray
    curb_right_d_m: np.ndarray
    road_type: np.ndarray
    stops: tuple[RouteStop, ...] = ()
    crosswalks: tuple[RouteCrosswalk, ...] = ()
    stop_lines: tuple[RouteStopLine, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.s_m)
        for name in ("speed_limit_mps", "lane_left_d_m", "lane_right_d_m", "curb_right_d_m", "road_type"):
            arr = getattr(self, name)
            if arr.shape != (n,):
                raise MapError(f"SLayerDatabase.{name}: expected shape ({n},), got {arr.shape}")
            arr.setflags(write=False)
        if self.step_m <= 0:
            raise MapError(f"SLayerDatabase.step_m: expected a positive step, got {self.step_m}")

    @property
    def length_m(self) -> float:
        return self.centerline.length_m

    def record_index(self, s_m: float) -> int:
        """Index of the record at or just before ``s_m`` (wrapped on a loop, clamped otherwise)."""
        if self.centerline.closed:
            s_m %= self.length_m
        return int(min(max(int(s_m // self.step_m), 0), len(self.s_m) - 1))

    def speed_limit_at(self, s_m: float) -> float:
        return float(self.speed_limit_mps[self.record_index(s_m)])

    def lane_right_at(self, s_m: float) -> float:
        return float(self.lane_right_d_m[self.record_index(s_m)])

    def curb_right_at(self, s_m: float) -> float:
        return float(self.curb_right_d_m[self.record_index(s_m)])
