"""Local path planners by name: the run configuration's ``[stack] planner`` selects one here.

Every planner is built with the same inputs (the route, the vehicle's half-width and body extent,
the curb lookup) and answers :class:`PathPlanner`'s ``plan`` each planning cycle.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Protocol

from lastmile.core.errors import ConfigError
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, Trajectory
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.planning.lattice_planner import LatticePlanner
from lastmile.planning.local_path import CurbLookup, LocalPathConfig, LocalPathPlanner
from lastmile.planning.pass_path import OffsetPassPlanner
from lastmile.planning.road_edge import BodyPlacement, DrivableLookup
from lastmile.planning.snow_lion_behaviour import SnowLionBehaviourPlanner


class PlannerName(StrEnum):
    """Local path planners by name."""

    POTENTIAL_FIELD_BEZIER = "potential_field_bezier"
    """WATonoBus: potential-field nudge inside the lane, Bezier pull-over and merge curves."""
    OFFSET_PASS = "offset_pass"
    """The same, and passes a stationary obstacle blocking the lane through the adjacent lane when
    decision orders it: a lattice of quintic lane-offset moves checked against the road surface and
    every track (:mod:`lastmile.planning.pass_path`)."""
    SNOW_LION_BEHAVIOUR = "snow_lion_behaviour"
    """Snow Lion's behaviour planner: scenario tags on the route choose the lateral-offset candidates,
    obstacle inflation and reference speed; d_t = argmin(J_s + J_d + J_o + J_dyn) with the 1/f_p
    guard, the truncation flag and observation areas at unprotected intersections; passes, pull-overs
    and merges as ``offset_pass`` (:mod:`lastmile.planning.snow_lion_behaviour`)."""
    LATTICE = "lattice"
    """aUToronto's local planner: A* over a lattice of quintic edges on the route lane and its sibling
    lanelets (the opposite lane while decision allows a pass), BFS-limited obstacle pruning, a stop
    before a full blockage; pull-overs and merges as ``offset_pass``
    (:mod:`lastmile.planning.lattice_planner`)."""


PASSING_PLANNERS = frozenset({PlannerName.OFFSET_PASS, PlannerName.SNOW_LION_BEHAVIOUR, PlannerName.LATTICE})
"""Planners that can plan a pass: with one of these, decision orders passes (``decision.pass_rule``)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PlannerInputs:
    """What every path planner is built with.

    Attributes:
        route: the service route's centreline.
        half_width_m: half the vehicle's width.
        curb_right_d_m: route s -> signed curb offset (NaN where there is none).
        body_behind_m, body_ahead_m: the body's extent behind and ahead of the path point.
        drivable: the map's drivable-area test ((N, 2) points -> (N,) bool), for passes and to keep
            the pull-over's body on the road.
        max_curvature_1pm: the tightest curvature the vehicle steers.
        layers: the route's s-layer records (scenario tags and lane widths for the behaviour planner).
        wheelbase_m: rear to front axle (0: the body is not checked against the road's edge).
        rear_steer_above_1pm: where the route bends more than this the rear wheels steer too (None:
            a front-steered vehicle); see ``road_edge.rear_steers``.
    """

    route: Polyline
    half_width_m: float
    curb_right_d_m: CurbLookup | None = None
    body_behind_m: float = 0.0
    body_ahead_m: float = 0.0
    drivable: DrivableLookup | None = None
    max_curvature_1pm: float = 0.2
    layers: SLayerDatabase | None = None
    wheelbase_m: float = 0.0
    rear_steer_above_1pm: float | None = None

    def body(self) -> BodyPlacement | None:
        """How the body lies along a path, or None when it is not known well enough to check."""
        if self.wheelbase_m <= 0.0 or self.body_ahead_m <= 0.0:
            return None
        return BodyPlacement(
            behind_m=self.body_behind_m,
            ahead_m=self.body_ahead_m,
            half_width_m=self.half_width_m,
            wheelbase_m=self.wheelbase_m,
            rear_steer_above_1pm=self.rear_steer_above_1pm,
        )


class PathPlanner(Protocol):
    """Plans the geometric path each planning cycle."""

    def plan(
        self,
        stamp: Stamp,
        ego_s_m: float,
        ego_d_m: float,
        decision: BehaviourDecision,
        obstacles: list[RouteObstacle],
    ) -> Trajectory: ...


def _shared(inputs: PlannerInputs) -> dict[str, Any]:
    """The keyword arguments every planner takes from the inputs."""
    return {
        "curb_right_d_m": inputs.curb_right_d_m,
        "body_behind_m": inputs.body_behind_m,
        "body_ahead_m": inputs.body_ahead_m,
        "drivable": inputs.drivable,
        "body": inputs.body(),
    }


def _potential_field_bezier(inputs: PlannerInputs, config: LocalPathConfig) -> PathPlanner:
    return LocalPathPlanner(inputs.route, inputs.half_width_m, config, **_shared(inputs))


def _offset_pass(inputs: PlannerInputs, config: LocalPathConfig) -> PathPlanner:
    return OffsetPassPlanner(
        inputs.route,
        inputs.half_width_m,
        config,
        max_curvature_1pm=inputs.max_curvature_1pm,
        **_shared(inputs),
    )


def _on_the_map(
    planner: type[SnowLionBehaviourPlanner | LatticePlanner],
) -> Callable[[PlannerInputs, LocalPathConfig], PathPlanner]:
    """The factory of a planner that reads the route's s-layer records (tags, lanes) besides the path."""

    def make(inputs: PlannerInputs, config: LocalPathConfig) -> PathPlanner:
        return planner(
            inputs.route,
            inputs.half_width_m,
            config,
            max_curvature_1pm=inputs.max_curvature_1pm,
            layers=inputs.layers,
            **_shared(inputs),
        )

    return make


PATH_PLANNERS: dict[PlannerName, Callable[[PlannerInputs, LocalPathConfig], PathPlanner]] = {
    PlannerName.POTENTIAL_FIELD_BEZIER: _potential_field_bezier,
    PlannerName.OFFSET_PASS: _offset_pass,
    PlannerName.SNOW_LION_BEHAVIOUR: _on_the_map(SnowLionBehaviourPlanner),
    PlannerName.LATTICE: _on_the_map(LatticePlanner),
}


def make_path_planner(
    name: PlannerName | str, inputs: PlannerInputs, config: LocalPathConfig | None = None
) -> PathPlanner:
    """The planner registered as ``name`` (a plain string is checked against the names)."""
    try:
        key = PlannerName(name)
    except ValueError:
        known = [n.value for n in PlannerName]
        raise ConfigError(f"planner: expected one of {known}, got {name!r}") from None
    return PATH_PLANNERS[key](inputs, config or LocalPathConfig())
