"""Stop points every behaviour state respects: obstacles in the path, cut-ins, crosswalks, the fail-safe."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from lastmile.core.objects import TrackedObjects
from lastmile.core.polyline import Polyline
from lastmile.core.predictions import PredictedPaths
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.safety_messages import FailSafeLevel, SafetyDirective
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import StopReason
from lastmile.decision.crosswalk_yield import crosswalk_yields
from lastmile.decision.decision_config import DecisionConfig
from lastmile.decision.traffic_light_rule import comfortable_stop_m
from lastmile.decision.vehicle_cut_in import predicted_cut_ins
from lastmile.hdmap.layers import RouteCrosswalk


@dataclass(slots=True)
class StopConstraint:
    """A point the shuttle's front must stop at.

    Attributes:
        stop_front_s_m: route s of the front bumper at the stop point.
        kind: what it is for (an object class, ``crosswalk``, ``stop_line``, ``spot`` ...), shown in the
            decision's reason.
        track_id: the track that causes it (-1: none).
        emergency_ok: an emergency stop may be ordered when this point can no longer be reached
            comfortably (an obstacle, not a rule or a prediction).
    """

    stop_front_s_m: float
    kind: str
    track_id: int = -1
    emergency_ok: bool = True
    reason: StopReason = StopReason.OBSTACLE


def lead_stop_s_m(s_m: float, length_m: float, speed_along_mps: float, lead_decel_mps2: float) -> float:
    """Route s of the rear of a lead at ``s_m`` once it has stopped: a lead moving along the route
    stops where it would stop braking at ``lead_decel_mps2``, and eq. (2) applies to that point (one
    coming towards the shuttle, or crossing, is taken as standing)."""
    moving_away = max(speed_along_mps, 0.0)
    return s_m - length_m / 2.0 + moving_away**2 / (2.0 * lead_decel_mps2)


def in_path_constraints(
    obstacles: list[RouteObstacle],
    speed_mps: float,
    path: Polyline | None,
    geometry: VehicleGeometry,
    config: DecisionConfig,
    front_s_m: float,
    kerbside_ids: frozenset[int] = frozenset(),
    unsettled_ids: frozenset[int] = frozenset(),
) -> list[StopConstraint]:
    """Obstacles in (or about to enter) the corridor swept along the planned path ``path``.

    The corridor is the body's half width, the obstacle's, and ``corridor_margin_m``; for the tracks
    in ``kerbside_ids`` (standing unclassified objects centred off the road, at the kerb a pull-over
    approaches) ``kerbside_margin_m`` instead.

    A track moving along the route with its centre more than ``behind_front_ignore_m`` behind the
    front is beside or behind the shuttle, going its way: not one to stop for. For the tracks in
    ``unsettled_ids`` (unclassified, only just tracked) that holds as soon as the centre is behind the
    front: nothing reaches the shuttle's side unseen by a sensor that sees all round, so a new one
    there is a precipitation echo near the sensor, not a road user overtaking (default service, snow,
    raw: a 0.16 m echo 0.3-0.6 s old keeping pace beside the body as the shuttle merged out of a bay
    was taken for a lead, and the stop ramped in at -1.92 m/s^3). Ahead of the front every track
    counts from birth, as the emergency stop needs.

    Stop points are in the front's lap (``front_s_m`` plus the obstacle's distance ahead), never the
    obstacle's own route s: on a loop, an obstacle just past the loop's start, seen from just before
    it, has a route s near 0, and a stop point there reads as a whole lap behind the front (an
    emergency stop that never clears; the 192 m Lanelet2 example loop in snow, raw perception)."""
    g, c = geometry, config
    steps = c.in_path_prediction_steps
    out: list[StopConstraint] = []
    for o in obstacles:
        if o.ds_m < -g.length_m or o.ds_m > c.in_path_lookahead_m:
            continue
        margin = c.kerbside_margin_m if o.track_id in kerbside_ids else c.corridor_margin_m
        half = g.width_m / 2.0 + o.width_m / 2.0 + margin
        # Constant-velocity prediction over the time the shuttle needs to get there (Snow Lion).
        horizon = (
            min(c.vulnerable_horizon_s, max(o.ds_m, 0.0) / max(speed_mps, c.vulnerable_reach_min_speed_mps))
            if o.cls.vulnerable
            else 0.0
        )
        # Offset of the planned path from the route where the obstacle is (pull-over, nudge).
        path_d = o.d_m - path.project(o.x_m, o.y_m).d_m if path is not None else 0.0
        hit = any(abs(o.d_m + o.v_d_mps * horizon * k / steps - path_d) < half for k in range(steps + 1))
        if not hit:
            continue
        behind_ignored_m = 0.0 if o.track_id in unsettled_ids else c.behind_front_ignore_m
        if o.ds_m < -behind_ignored_m and o.v_s_mps > 0.0:
            continue  # behind the front, moving with us: not ours to stop for
        s_in_lap = front_s_m + o.ds_m  # o.ds_m: from the front, along the loop
        stop_s = lead_stop_s_m(s_in_lap, o.length_m, o.v_s_mps, c.lead_decel_mps2) - c.min_gap_m
        out.append(StopConstraint(stop_s, o.cls.name.lower(), o.track_id, reason=StopReason.OBSTACLE))
    return out


def cut_in_constraints(
    obstacles: list[RouteObstacle],
    predictions: PredictedPaths | None,
    route: Polyline,
    path: Polyline | None,
    front_s_m: float,
    speed_mps: float,
    geometry: VehicleGeometry,
    config: DecisionConfig,
) -> list[StopConstraint]:
    """Vehicles the lane-following prediction brings into the corridor ahead before the shuttle
    passes (``vehicle_cut_in``): followed like a lead from where they enter. Never an emergency
    stop on a prediction alone; once the car is in the corridor the in-path test takes over."""
    c = config
    cut_ins = predicted_cut_ins(
        obstacles,
        predictions,
        route,
        path,
        front_s_m,
        speed_mps,
        geometry.width_m / 2.0 + c.corridor_margin_m,
        horizon_s=c.vehicle_prediction_horizon_s,
        pass_margin_s=c.cut_in_pass_margin_s,
    )
    return [
        StopConstraint(
            lead_stop_s_m(
                front_s_m + route.ds_m(front_s_m, k.entry_s_m),  # in the front's lap (see in_path)
                k.length_m,
                k.speed_along_mps,
                c.lead_decel_mps2,
            )
            - c.min_gap_m,
            "cut-in",
            k.track_id,
            emergency_ok=False,
            reason=StopReason.CUT_IN,
        )
        for k in cut_ins
    ]


def crosswalk_constraints(
    crosswalks: Sequence[RouteCrosswalk],
    route: Polyline,
    tracks: TrackedObjects,
    front_s_m: float,
    speed_mps: float,
    predictions: PredictedPaths | None,
    geometry: VehicleGeometry,
    config: DecisionConfig,
    unsettled: frozenset[int] = frozenset(),
    may_pass: bool = False,
    yielding_to: frozenset[int] = frozenset(),
) -> list[StopConstraint]:
    """Yield at a crosswalk to the people ``crosswalk_yield`` finds there or about to be; to an
    ``unsettled`` track only while a comfortable stop still fits (``comfortable_stop_m``); with
    ``may_pass`` (no yield under way: one being braked for is kept), where none fits, not to someone
    who reaches the corridor only ``crosswalk_pass_margin_s`` after the shuttle has cleared the
    crossing; to a track in ``yielding_to`` (a yield under way) whether settled or not."""
    return [
        StopConstraint(stop_s, "crosswalk", tid, emergency_ok=False, reason=StopReason.CROSSWALK)
        for stop_s, tid in crosswalk_yields(
            crosswalks,
            route,
            tracks,
            front_s_m,
            speed_mps,
            geometry.length_m,
            predictions,
            margin_m=config.crosswalk_margin_m,
            lookahead_s=config.crosswalk_lookahead_s,
            gap_m=config.min_gap_m,
            comfort_decel_mps2=config.traffic_lights.comfort_decel_mps2,
            unsettled=unsettled,
            comfortable_room_m=comfortable_stop_m(speed_mps, config.traffic_lights),
            corridor_half_m=geometry.width_m / 2.0 + config.corridor_margin_m,
            pass_margin_s=config.crosswalk_pass_margin_s if may_pass else math.inf,
            yielding_to=yielding_to,
        )
    ]


def safety_constraints(
    directive: SafetyDirective | None, cap_mps: float
) -> tuple[float, list[StopConstraint]]:
    """The fail-safe's directive as a speed cap and, for a minimal risk manoeuvre, a stop point.

    The e-stop itself is not here: it changes the state (``BehaviourStateMachine.request_emergency``).

    Returns:
        The speed cap (``cap_mps`` or the directive's, whichever is lower) and the stop points.
    """
    if directive is None or directive.level == FailSafeLevel.NONE:
        return cap_mps, []
    if directive.speed_cap_mps is not None:
        cap_mps = min(cap_mps, directive.speed_cap_mps)
    if directive.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE and directive.mrm_stop_s_m is not None:
        # A comfortable stop at the arbiter's point (never an emergency brake for it).
        return cap_mps, [
            StopConstraint(
                directive.mrm_stop_s_m,
                "minimal risk manoeuvre",
                emergency_ok=False,
                reason=StopReason.MINIMAL_RISK_MANOEUVRE,
            )
        ]
    return cap_mps, []
