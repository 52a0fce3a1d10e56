"""Parameters of aUToronto's lattice planner (:mod:`lastmile.planning.lattice_planner`).

In a run configuration: ``[stack.path.lattice]``.
"""

from __future__ import annotations

from dataclasses import dataclass

from lastmile.core.errors import ConfigError


@dataclass(frozen=True, slots=True, kw_only=True)
class LatticeConfig:
    """Parameters of :class:`~lastmile.planning.lattice_planner.LatticePlanner`.

    The body clearances, the move's comfort and the speed tracks are timed at are the offset-pass
    planner's (``[stack.path.passing]``: one value, which decision's pass rule checks too).

    Attributes:
        station_spacing_m: route spacing of the lattice's stations (aUToronto 7.1.3: edges to points
            10-15 m ahead). On a loop it is rounded so that a whole number of stations fits.
        max_span_stations: a lane change may span up to this many stations (a 3.5 m change over one
            12 m edge bends at 0.14 /m, beyond comfort at 4 m/s; longer ones are the comfortable moves).
        probe_m: a neighbouring lanelet is looked for this far beyond the route lane's edge (half of
            a narrow 3 m lane).
        parallel_cos: a neighbour counts as a sibling (same direction) or the opposite lane when its
            heading's cosine with the route's is above this (or below its negative); lanelets at an
            angle (junction branches) are no lanes beside the route.
        horizon_m: the search's goal lies this far ahead of the rear axle (beyond the path's 60 m).
        prune_depth: obstacles are checked only on edges within this many edges of the shuttle
            (aUToronto's BFS-limited pruning; the rest of the lattice is searched unchecked).
        w_length: cost per metre of path.
        w_lane_change: cost of each lane change (in metres of path).
        w_deviation: cost per metre driven off the route's lane (aUToronto's deviation penalty).
        w_lateral_accel: cost per m/s^2 of an edge's peak lateral acceleration at the passing speed.
        w_obstacle: cost per 1/m of the least clearance to a track beside an edge.
        stop_gap_m: at a full blockage the front stops this far before the first obstacle (Snow
            Lion's truncation gap, ``BehaviourConfig.stop_gap_m``).
        lane_margin_m: inside its own lane the body may shift to clear an obstacle (as the potential
            field does) up to this far from the lane's edges.
    """

    station_spacing_m: float = 12.0
    max_span_stations: int = 3
    probe_m: float = 1.5
    parallel_cos: float = 0.9
    horizon_m: float = 72.0
    prune_depth: int = 5
    w_length: float = 1.0
    w_lane_change: float = 10.0
    w_deviation: float = 0.5
    w_lateral_accel: float = 5.0
    w_obstacle: float = 2.0
    stop_gap_m: float = 3.0
    lane_margin_m: float = 0.1

    def __post_init__(self) -> None:
        if not 5.0 <= self.station_spacing_m <= 30.0:
            raise ConfigError(
                f"[stack.path.lattice] station_spacing_m: expected 5-30 m, got {self.station_spacing_m}"
            )
        if self.max_span_stations < 1 or self.prune_depth < 1:
            raise ConfigError(
                "[stack.path.lattice] max_span_stations, prune_depth: expected at least 1, got "
                f"{self.max_span_stations}, {self.prune_depth}"
            )
        if self.horizon_m < self.station_spacing_m:
            raise ConfigError(
                f"[stack.path.lattice] horizon_m: expected at least station_spacing_m "
                f"({self.station_spacing_m}), got {self.horizon_m}"
            )
