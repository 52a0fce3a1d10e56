"""aUToronto's local planner (7.1.3): A* over a lattice of the route lane and its sibling lanelets.

``[stack] planner = "lattice"``. Each planning cycle in normal driving (and through junctions) the
search (:mod:`lastmile.planning.lattice_search`) finds the cheapest path over the map's lattice
(:mod:`lastmile.planning.lattice_graph`) from the shuttle's planned lateral state to 72 m ahead:

- nodes on the route lane always, on a same-direction sibling lanelet always (the map lets a lane
  change enter it), on the opposite lane only while decision's pass rule has approved a pass (the
  opposite lane is clear: ``decision.pass_rule``, the same rule the offset-pass planner obeys);
- the path found keeps to the route lane: the route lane's own path is driven, the potential field's
  in-lane nudge, and the look-out offset while decision waits to pass (as ``offset_pass``);
- the path found leaves the route lane (a pass, or a sibling around a blockage): its quintics are
  the path;
- no path (every lane blocked, or the opposite one not allowed): a full blockage. The path is kept in
  the lane and truncated: ``Trajectory.truncated`` is set and ``stop_at_route_s_m`` puts the front
  ``stop_gap_m`` before the first obstacle that blocked it; the stack stops at the nearer of that and
  decision's stop.

Pull-overs, onboarding, merges and emergency stops are the offset-pass planner's paths (the class
extends it), so stops are served as with the default planner.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lastmile.core.geometry import FloatArray
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, Trajectory
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.planning.lattice_config import LatticeConfig
from lastmile.planning.lattice_graph import LatticeGraph, VehicleBody
from lastmile.planning.lattice_search import (
    LatticePath,
    LatticeSearch,
    SearchObstacle,
    SearchRequest,
    SearchResult,
)
from lastmile.planning.local_path import CurbLookup, LocalPathConfig, LocalPathPlanner
from lastmile.planning.pass_path import OffsetPassPlanner
from lastmile.planning.road_edge import BodyPlacement, DrivableLookup

NEAR_ROUTE_M = 20.0
"""Tracks within this of the searched stretch (either end) are handed to the search."""


class LatticePlanner(OffsetPassPlanner):
    """A* over the map's lattice in normal driving; the offset-pass planner's paths otherwise.

    Args:
        layers: the route's s-layer records and map (None: the route lane alone, for synthetic tests).
    """

    def __init__(
        self,
        route: Polyline,
        half_width_m: float,
        config: LocalPathConfig | None = None,
        curb_right_d_m: CurbLookup | None = None,
        body_behind_m: float = 0.0,
        body_ahead_m: float = 0.0,
        drivable: DrivableLookup | None = None,
        max_curvature_1pm: float = 0.2,
        layers: SLayerDatabase | None = None,
        body: BodyPlacement | None = None,
    ) -> None:
        super().__init__(
            route,
            half_width_m,
            config,
            curb_right_d_m,
            body_behind_m,
            body_ahead_m,
            drivable,
            max_curvature_1pm,
            body,
        )
        self.lattice_config: LatticeConfig = self.config.lattice or LatticeConfig()
        vehicle = VehicleBody(
            behind_m=body_behind_m,
            ahead_m=body_ahead_m,
            half_width_m=half_width_m,
            max_curvature_1pm=max_curvature_1pm,
        )
        self.graph = LatticeGraph(
            layers, route, vehicle, self.lattice_config, drivable, self.pass_config.steer_limit_share
        )
        self.search = LatticeSearch(self.graph, drivable)
        self.last_result: SearchResult | None = None
        self.last_path: LatticePath | None = None
        self._ego_s = 0.0
        self._stop_front_s: float | None = None

    def plan(
        self,
        stamp: Stamp,
        ego_s_m: float,
        ego_d_m: float,
        decision: BehaviourDecision,
        obstacles: list[RouteObstacle],
    ) -> Trajectory:
        self._ego_s = ego_s_m
        self._stop_front_s = None
        trajectory = super().plan(stamp, ego_s_m, ego_d_m, decision, obstacles)
        if self._stop_front_s is None:
            return trajectory
        stop = self._stop_front_s % self.route.length_m if self.route.closed else self._stop_front_s
        return dataclasses.replace(trajectory, stop_at_route_s_m=stop, truncated=True)

    def offsets_m(
        self, s_m: FloatArray, decision: BehaviourDecision, obstacles: list[RouteObstacle], ego_d_m: float
    ) -> FloatArray:
        if decision.state not in (BehaviourState.NORMAL_DRIVING, BehaviourState.INTERSECTION):
            self.last_result, self.last_path = None, None
            return super().offsets_m(s_m, decision, obstacles, ego_d_m)
        req = decision.pass_request
        result = self.search.search(self._request(decision, obstacles, ego_d_m))
        kept = self.last_path
        self.last_result, self.last_path = result, result.path
        base = LocalPathPlanner.offsets_m(self, s_m, decision, obstacles, ego_d_m)
        if req is not None:
            base = np.maximum(base, self._lookout_m(s_m, req, self._ego_s))
        if result.path is None:
            if result.blocked_at_s_m is not None:
                self._stop_front_s = result.blocked_at_s_m - self.lattice_config.stop_gap_m
            lap = None if kept is None else self._lap_on(kept)
            if (
                kept is not None
                and lap is not None
                and abs(kept.d_at(np.array([self._ego_s + lap]))[0]) >= 1.0
            ):
                # Blocked out of the lane: hold the path being driven (swerving back towards a lane
                # that is blocked would not help) and stop on it.
                self.last_path = kept
                return kept.d_at(np.asarray(s_m) + lap)
            self.last_path = None
            return base
        if not result.path.leaves_route_lane and abs(result.path.d_at(np.array([self._ego_s]))[0]) < 1.0:
            # The in-lane path is driven, not the search's: the next search starts from the measured
            # offset (starting from the unused lattice path put its state 1 m from the shuttle's).
            self.last_path = None
            return base
        return result.path.d_at(s_m)

    def _lap_on(self, path: LatticePath) -> float | None:
        """What brings the rear axle's s into the path's s (a lap on a loop), or None when the path
        does not reach it."""
        laps = (0.0, self.route.length_m, -self.route.length_m) if self.route.closed else (0.0,)
        for lap in laps:
            if path.state_at(self._ego_s + lap) is not None:
                return lap
        return None

    def _planned_state(self, ego_d_m: float) -> tuple[float, float, float]:
        """The lateral state the last path planned at the rear axle (the measured offset without one)."""
        path = self.last_path
        lap = None if path is None else self._lap_on(path)
        state = None if path is None or lap is None else path.state_at(self._ego_s + lap)
        return (ego_d_m, 0.0, 0.0) if state is None else state

    def _request(
        self, decision: BehaviourDecision, obstacles: list[RouteObstacle], ego_d_m: float
    ) -> SearchRequest:
        c, lc = self.pass_config, self.lattice_config
        ego = self._ego_s
        near = []
        for o in obstacles:
            s = ego + self.route.ds_m(ego, o.s_m) if self.route.closed else o.s_m
            if -NEAR_ROUTE_M <= s - ego <= lc.horizon_m + NEAR_ROUTE_M:
                near.append(
                    SearchObstacle(
                        s_m=s,
                        d_m=o.d_m,
                        length_m=o.length_m,
                        width_m=o.width_m,
                        v_s_mps=o.v_s_mps,
                        v_d_mps=o.v_d_mps,
                    )
                )
        req = decision.pass_request
        return SearchRequest(
            ego_s_m=ego,
            start=self._planned_state(ego_d_m),
            allow_opposite=req is not None and req.approved,
            obstacles=tuple(near),
            speed_mps=c.speed_mps,
            clearance_m=c.clearance_m,
            min_clearance_m=c.min_clearance_m,
            in_lane_clearance_m=self.config.field.clearance_m,
            lane_half_width_m=self.config.lane_half_width_m,
            return_gap_m=c.return_gap_m,
        )
