"""WATonoBus's s-coordinate layer database: the route cut at equal s, a record per step (Fig. 7)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import MapError
from lastmile.core.polyline import Polyline
from lastmile.hdmap.lane_change import KeepClear
from lastmile.hdmap.model import BusStop, Crosswalk, HDMap, Landmark, StopLine

# road_type codes
NORMAL, INTERSECTION, CROSSWALK, BUS_BAY, DRIVEWAY = 0, 1, 2, 3, 4
# intersection_type codes
NO_INTERSECTION, ALL_WAY_STOP, UNCONTROLLED, SIGNALISED, PRIORITY = 0, 1, 2, 3, 4
LANDMARK_RADIUS_M = 40.0  # a landmark is "nearby" when a sensor on the shuttle could see it


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
        road_type: (N,) int8 codes: 0 normal, 1 intersection (a controlled junction: all-way stop,
            signal or right-of-way rule), 2 crosswalk, 3 bus bay, 4 driveway (a junction without
            control, such as a parking-lot entrance). Junctions come from the lanelet topology (the
            route lanelet's predecessor branches, its successor merges); a ``turn_direction`` tag alone
            makes no junction.
        intersection_type: (N,) int8 codes: 0 none, 1 all-way stop, 2 uncontrolled junction,
            3 signalised junction, 4 priority junction (a right-of-way rule).
        lanelet_id: (N,) int64, the route lanelet each record lies on.
        landmark_start, landmark_index: landmarks within LANDMARK_RADIUS_M of record i are
            ``hdmap.landmarks[j]`` for j in ``landmark_index[landmark_start[i]:landmark_start[i + 1]]``.
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
    intersection_type: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    lanelet_id: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    landmark_start: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    landmark_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        n = len(self.s_m)
        # Hand-made databases (tests) may leave the map-derived layers out: no junctions, no landmarks.
        for name, size in (("intersection_type", n), ("lanelet_id", n), ("landmark_start", n + 1)):
            arr = getattr(self, name)
            if arr.size == 0 and size > 0:
                object.__setattr__(self, name, np.zeros(size, dtype=arr.dtype))
        names = ("speed_limit_mps", "lane_left_d_m", "lane_right_d_m", "curb_right_d_m", "road_type")
        for name in (*names, "intersection_type", "lanelet_id"):
            arr = getattr(self, name)
            if arr.shape != (n,):
                raise MapError(f"SLayerDatabase.{name}: expected shape ({n},), got {arr.shape}")
            arr.setflags(write=False)
        if self.step_m <= 0:
            raise MapError(f"SLayerDatabase.step_m: expected a positive step, got {self.step_m}")
        if self.landmark_start.shape != (n + 1,):
            raise MapError(
                f"SLayerDatabase.landmark_start: expected shape ({n + 1},), got {self.landmark_start.shape}"
            )

    @classmethod
    def build(
        cls,
        hdmap: HDMap,
        lanelet_ids: tuple[int, ...],
        step_m: float = 1.0,
        closed: bool = False,
        unmapped_speed_limit_mps: float | None = None,
        keep_clear: tuple[KeepClear, ...] = (),
        steerable: bool = False,
    ) -> SLayerDatabase:
        """Cut the route through ``lanelet_ids`` every ``step_m`` and fill every layer from the map.

        Args:
            unmapped_speed_limit_mps: the limit on route lanelets whose map states none (the route
                file's); None: such a lanelet is an error.
            keep_clear: stretches the route's lane changes keep out of (``routing.route_polyline``).
            steerable: corners the shuttle cannot steer rounded (``routing.route_polyline``).

        Raises:
            MapError: a bad step, a route lanelet without a mapped speed limit and no limit given.
        """
        from lastmile.hdmap.layer_builder import build_layers  # the builder needs this class itself

        return build_layers(
            cls, hdmap, lanelet_ids, step_m, closed, unmapped_speed_limit_mps, keep_clear, steerable
        )

    @property
    def length_m(self) -> float:
        return self.centerline.length_m

    def record_index(self, s_m: float) -> int:
        """Index of the record at or just before ``s_m`` (wrapped on a loop, clamped otherwise)."""
        if self.centerline.closed:
            s_m %= self.length_m
        return int(min(max(int(s_m // self.step_m), 0), len(self.s_m) - 1))

    def record_indices(self, s_m: np.ndarray) -> np.ndarray:
        """Vectorised ``record_index`` for an array of s."""
        s = np.asarray(s_m, dtype=float)
        if self.centerline.closed:
            s = s % self.length_m
        return np.clip((s // self.step_m).astype(np.int64), 0, len(self.s_m) - 1)

    def speed_limit_at(self, s_m: float) -> float:
        return float(self.speed_limit_mps[self.record_index(s_m)])

    def lane_right_at(self, s_m: float) -> float:
        return float(self.lane_right_d_m[self.record_index(s_m)])

    def curb_right_at(self, s_m: float) -> float:
        return float(self.curb_right_d_m[self.record_index(s_m)])

    @property
    def signal_stop_lines(self) -> tuple[RouteStopLine, ...]:
        """Stop lines on the route controlled by a traffic signal (``stop_line.signal_id``), in s order."""
        return tuple(rl for rl in self.stop_lines if rl.stop_line.signal_id is not None)

    def landmarks_near(self, s_m: float) -> tuple[Landmark, ...]:
        """Landmarks a sensor could see from the record at ``s_m``, nearest first."""
        i = self.record_index(s_m)
        idx = self.landmark_index[self.landmark_start[i] : self.landmark_start[i + 1]]
        return tuple(self.hdmap.landmarks[j] for j in idx.tolist())
