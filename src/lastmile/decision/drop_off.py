"""Snow Lion's unscheduled drop-off: on a passenger's button, stop at the next safe kerb, wait, resume.

Snow Lion ("A navigation task with global routing"): the task manager uses the function button's status
to truncate the global route to a temporary destination when a passenger asks for an unscheduled
drop-off; once halted, the vehicle stays stationary for a predefined period (typically 8 s) and checks
that no pedestrian is near before it resumes the original task.

Here the temporary destination is the first **safe place to stop** ahead (:class:`DropOffPlaces`),
reached by the same pull-over to the kerb as a stop (the curb-gap target kept), served by the same
door cycle, and left by the same merge (its rear-traffic checks). The safe places come from the route's
s-layer records, once per route:

- the lane's own right edge is a kerb (``kerb_lane_edge_m``): a kerb further out is a bus bay or its
  taper, a parking lane or another lane, which the pull-over does not cross; no kerb (a junction mouth,
  a driveway) is no place to stop;
- plain road (road type normal): not in an intersection box, a driveway, on a crosswalk or a bus stop's
  platform, and the body at least ``crosswalk_clear_m`` from a crosswalk, ``junction_clear_m`` from a
  junction or driveway and ``stop_line_clear_m`` before a stop line (StVO section 12: no halting on a
  pedestrian crossing or within 5 m before it, nor within 10 m before a traffic light or sign it would
  hide; no parking within 5 m of an intersection);
- not on a sharp bend (StVO section 12(1): no halting at sharp bends; ``max_curvature_1pm``);
- far enough ahead: the pull-over's route length (``DecisionConfig.transition_m``) and the distance the
  speed law needs to stop comfortably from the present speed
  (:func:`~lastmile.decision.traffic_light_rule.comfortable_stop_m`), whichever is longer;
- free: no standing tracked obstacle where the body rests, in the second half of the approach or in
  the merge room ahead (:func:`~lastmile.decision.pullover_spot.choose_spot`, as at a stop); moving
  traffic is left to the in-path rule.

The search ends at the next stop's platform (or where its pull-over begins, ``stop_approach_m`` before
it, when the stop is wanted anyway): with no safe place before it, the rider gets off there (the stop
is requested for them). Once halted: the door cycle of a stop (``door_cycle``), at least
``wait_s`` standing, then no pedestrian, cyclist or animal track within ``clear_radius_m`` of the
body on the door's side for ``clear_for_s``, then the merge.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourState, StopReason
from lastmile.decision.behaviour_memory import (
    BehaviourMemory,
    Boarding,
    Cycle,
    DecisionContext,
    DropOffVisit,
    Outcome,
)
from lastmile.decision.drop_off_config import DropOffConfig
from lastmile.decision.pullover_spot import SpotRequest, choose_spot
from lastmile.decision.stop_constraints import StopConstraint
from lastmile.decision.stop_service import door_cycle
from lastmile.decision.traffic_light_rule import comfortable_stop_m
from lastmile.hdmap.layers import DRIVEWAY, INTERSECTION, NORMAL, SLayerDatabase

_X, _Y, _L, _W, _CLS = (TRACK_COLUMNS.index(c) for c in ("x_m", "y_m", "length_m", "width_m", "class_id"))


class DropOffPlaces:
    """Where along the route the shuttle may stop at the kerb for a drop-off (one flag per record)."""

    def __init__(self, layers: SLayerDatabase, config: DropOffConfig) -> None:
        self.layers = layers
        self.config = config
        self.allowed = self._allowed()
        self.allowed.setflags(write=False)

    def _allowed(self) -> np.ndarray:
        lay, c = self.layers, self.config
        curb, right = lay.curb_right_d_m, lay.lane_right_d_m
        with np.errstate(invalid="ignore"):
            kerbside = np.isfinite(curb) & (np.abs(curb - right) <= c.kerb_lane_edge_m)
        bends = np.abs(_curvature_1pm(lay)) > c.max_curvature_1pm
        ok = kerbside & (lay.road_type == NORMAL) & ~bends
        for s0, s1 in self._keep_out():
            ok[self._indices(s0, s1)] = False
        return ok

    def _keep_out(self) -> list[tuple[float, float]]:
        """Route s intervals no part of the body may be in: crosswalks, stop lines and junctions with
        their clearances, and bus-stop platforms."""
        lay, c = self.layers, self.config
        out = [
            (cw.s_start_m - c.crosswalk_clear_m, cw.s_end_m + c.crosswalk_clear_m) for cw in lay.crosswalks
        ]
        out += [(rl.s_m - c.stop_line_clear_m, rl.s_m + c.junction_clear_m) for rl in lay.stop_lines]
        out += [(rs.s_start_m, rs.s_end_m) for rs in lay.stops]
        for code in (INTERSECTION, DRIVEWAY):
            for s0, s1 in _runs(lay.s_m, lay.road_type == code, lay.step_m):
                out.append((s0 - c.junction_clear_m, s1 + c.junction_clear_m))
        return out

    def _indices(self, s0_m: float, s1_m: float) -> np.ndarray:
        step = self.layers.step_m
        return self.layers.record_indices(np.arange(s0_m, s1_m + step, step))

    def find(
        self,
        ctx: DecisionContext,
        front_s_m: float,
        earliest_ahead_m: float,
        limit_ahead_m: float,
        obstacles: list[RouteObstacle],
        preferred_ahead_m: float | None = None,
    ) -> tuple[float, float] | None:
        """(route s of the front bumper at the free safe spot nearest the preferred one, kerb d there),
        or None.

        Args:
            earliest_ahead_m: the nearest the front may stop (route metres ahead of it).
            preferred_ahead_m: where the front should stop if free (None: as early as allowed); the
                runs of safe records are tried in order, the first with a free spot wins.
            limit_ahead_m: the spot's front no further than this ahead (the next stop's platform).
            obstacles: the cycle's tracks on the route (``ds_m``: centre ahead of the front).
        """
        lay, dc, g = self.layers, ctx.config, ctx.geometry
        if not lay.centerline.closed:
            limit_ahead_m = min(limit_ahead_m, lay.length_m - front_s_m)
        if limit_ahead_m <= earliest_ahead_m:
            return None
        step = lay.step_m
        approach_m = dc.transition_m * dc.spot_transition_share
        # From behind the shuttle's own body: a spot it is close to stays where it is.
        back_m = g.length_m + approach_m if lay.centerline.closed else min(g.length_m + approach_m, front_s_m)
        # On the records' own grid, so a run starts where its first record does.
        first = math.floor((front_s_m - back_m) / step) * step
        ahead = np.arange(first, front_s_m + limit_ahead_m + dc.merge_room_m + step, step) - front_s_m
        idx = lay.record_indices(front_s_m + ahead)
        # Standing obstacles (a radar-tracked parked car wanders below the pass rule's moving speed) in
        # the same "metres ahead of the front" coordinate as the candidate spots; traffic moves on.
        seen = [
            dataclasses.replace(o, s_m=o.ds_m) for o in obstacles if o.speed_mps < dc.passing.moving_speed_mps
        ]
        for a, b in _runs(ahead, self.allowed[idx], step):
            curb_d = float(np.median(lay.curb_right_d_m[idx[(ahead >= a) & (ahead < b)]]))
            request = SpotRequest(
                platform_start_s_m=a,
                platform_end_s_m=min(b - dc.merge_room_m, limit_ahead_m),
                # Anything reaching into where the body rests blocks (its left side at the curb gap).
                bay_edge_d_m=curb_d + dc.curb_gap_target_m + g.width_m,
                curb_d_m=curb_d,
                vehicle_length_m=g.length_m,
                transition_m=approach_m,
                margin_m=dc.min_gap_m + dc.spot_extra_margin_m,
                preferred_front_s_m=earliest_ahead_m if preferred_ahead_m is None else preferred_ahead_m,
                exit_m=dc.merge_room_m,
                earliest_front_s_m=earliest_ahead_m,
            )
            spot = choose_spot(request, seen)
            if spot is not None:
                return front_s_m + spot, curb_d
        return None


CURVATURE_WINDOW_M = 2.0
"""Half the chord of the three points the route's curvature is taken through (``Polyline.curvature_at``'s)."""


def _curvature_1pm(layers: SLayerDatabase) -> np.ndarray:
    """(N,) the route's curvature at each record: ``Polyline.curvature_at``, for all records at once."""
    route, s, w = layers.centerline, layers.s_m, CURVATURE_WINDOW_M
    a, b, c = route.points_at(s - w), route.points_at(s), route.points_at(s + w)
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    denom = np.hypot(*(b - a).T) * np.hypot(*(c - b).T) * np.hypot(*(c - a).T)
    safe = np.where(denom < 1e-12, 1.0, denom)
    return np.where(denom < 1e-12, 0.0, 2.0 * cross / safe)


def _runs(s_m: np.ndarray, flags: np.ndarray, step_m: float) -> list[tuple[float, float]]:
    """[start, end) in s of each run of True in ``flags`` (records ``step_m`` apart)."""
    f = np.r_[False, np.asarray(flags, dtype=bool), False].astype(np.int8)
    edges = np.flatnonzero(np.diff(f))
    return [(float(s_m[i]), float(s_m[j - 1]) + step_m) for i, j in zip(edges[::2], edges[1::2], strict=True)]


def next_stop_ahead(ctx: DecisionContext, front_s_m: float) -> tuple[str, float] | None:
    """(id, metres ahead of the front to its platform) of the next stop on the route, if any."""
    best: tuple[str, float] | None = None
    for rs in ctx.layers.stops:
        ahead = ctx.ahead_m(rs.s_start_m, front_s_m)
        if ahead < 0.0 and ctx.route.closed:
            ahead += ctx.route.length_m
        if ahead > 0.0 and (best is None or ahead < best[1]):
            best = (rs.stop.id, ahead)
    return best


def pedestrian_near_door(
    tracks: TrackedObjects, pose: SE2, geometry: VehicleGeometry, radius_m: float
) -> tuple[int, float] | None:
    """(track id, gap in m) of the nearest pedestrian, cyclist or animal within ``radius_m`` of the body
    on the door's (right) side, else None. The gap is from the body's outline to the track's, each track
    taken as a disc of half its longer side. Only classified tracks count: an unclassified one at the
    kerb (a pole, a bin in LiDAR clusters) would hold the shuttle for ever."""
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    x0, x1 = -geometry.rear_overhang_m, geometry.length_m - geometry.rear_overhang_m
    half = geometry.width_m / 2.0
    best: tuple[int, float] | None = None
    for tid, row in zip(tracks.ids.tolist(), tracks.table.tolist(), strict=True):
        if not ObjectClass(int(row[_CLS])).vulnerable:
            continue
        dx, dy = row[_X] - pose.x_m, row[_Y] - pose.y_m
        bx, by = c * dx + s * dy, -s * dx + c * dy  # in the body frame (x forward, y left)
        if by > 0.0:
            continue  # the far side: the door opens to the right
        gap = math.hypot(max(x0 - bx, 0.0, bx - x1), max(abs(by) - half, 0.0)) - max(row[_L], row[_W]) / 2.0
        if gap <= radius_m and (best is None or gap < best[1]):
            best = (int(tid), max(gap, 0.0))
    return best


# --- the states of a drop-off ---------------------------------------------------------------------------
def start_drop_off(
    ctx: DecisionContext, mem: BehaviourMemory, cy: Cycle, places: DropOffPlaces
) -> Outcome | None:
    """In normal driving, with a drop-off pending: PULLOVER to the first safe spot; with none before
    the next stop, ask for that stop (the rider gets off there). None: nothing started this cycle."""
    dv = mem.drop_off
    if not ctx.mission.drop_off_pending:
        dv.deferred_stop_id = None
        return None
    nxt = next_stop_ahead(ctx, cy.front_s_m)
    if dv.deferred_stop_id is not None and nxt is not None and nxt[0] == dv.deferred_stop_id:
        return None  # on the way to the stop it was handed to
    dv.deferred_stop_id = None
    earliest = max(comfortable_stop_m(cy.inp.speed_mps, ctx.config.traffic_lights), ctx.config.transition_m)
    limit = places.config.search_m
    if nxt is not None:
        # A stop the shuttle will serve anyway is reached by its own pull-over, which begins
        # ``stop_approach_m`` before its platform: the drop-off must be done (and the shuttle out of
        # the kerb) before then, else the rider gets off at the stop.
        limit = nxt[1] - (ctx.config.stop_approach_m if ctx.mission.wants(nxt[0]) else 0.0)
    found = places.find(ctx, cy.front_s_m, earliest, limit, cy.obstacles)
    if found is None:
        if nxt is not None:
            ctx.mission.requested.add(nxt[0])
            dv.deferred_stop_id = nxt[0]
        return None
    mem.drop_off = DropOffVisit(spot_front_s_m=found[0], curb_d_m=found[1])
    why = f"drop-off requested: kerb {found[0] - cy.front_s_m:.0f} m ahead"
    mem.enter(BehaviourState.PULLOVER, cy.t_s, why)
    return dataclasses.replace(handle_drop_off_pullover(ctx, mem, cy, places), reason=why)


def handle_drop_off_pullover(
    ctx: DecisionContext, mem: BehaviourMemory, cy: Cycle, places: DropOffPlaces
) -> Outcome:
    """To the kerbside spot, re-chosen every cycle from what the tracker sees until committed (as a
    stop's); ONBOARDING once halted there."""
    c, dv = ctx.config, mem.drop_off
    assert dv.spot_front_s_m is not None
    if not dv.spot_committed:
        # The spot stays where it is while free (the pull-over curve is laid towards it); a car seen
        # parked there moves it further on, never nearer.
        here = ctx.ahead_m(dv.spot_front_s_m, cy.front_s_m)
        found = places.find(ctx, cy.front_s_m, here, here + c.spot_scan_m, cy.obstacles, here)
        if found is not None:  # none: keep the spot; the in-path test stops for what blocks it
            dv.spot_front_s_m, dv.curb_d_m = found
        if ctx.ahead_m(dv.spot_front_s_m + c.merge_room_m, cy.front_s_m) < c.spot_commit_m:
            dv.spot_committed = True
    cy.constraints.append(StopConstraint(dv.spot_front_s_m, "spot", -1, False, StopReason.DROP_OFF))
    ahead = ctx.ahead_m(dv.spot_front_s_m, cy.front_s_m)
    if abs(ahead) < c.spot_arrival_m and cy.inp.speed_mps < c.standstill_mps:
        mem.enter(BehaviourState.ONBOARDING, cy.t_s, "at drop-off spot")
        mem.boarding = Boarding()
        dv.halted_since_s = cy.t_s
    cap = cy.speed_cap_mps
    if ahead < c.stop_approach_m:
        cap = min(cap, c.pullover_speed_mps)
    return Outcome(cap, "pulling over: drop-off")


def handle_drop_off_onboarding(
    ctx: DecisionContext, mem: BehaviourMemory, cy: Cycle, config: DropOffConfig
) -> Outcome:
    """The door cycle of a stop; then, the door closed, at least ``wait_s`` standing and no pedestrian
    near the door's side for ``clear_for_s``; then MERGING (the drop-off is served)."""
    inp, t_s, dv = cy.inp, cy.t_s, mem.drop_off
    cy.constraints.append(StopConstraint(cy.front_s_m, "onboarding", -1, False, StopReason.ONBOARDING))
    if dv.halted_since_s is None:
        dv.halted_since_s = t_s
    door = door_cycle(ctx.config, mem.boarding, inp, t_s, cy.speed_cap_mps)
    if door is not None:
        return door
    near = pedestrian_near_door(inp.tracks, inp.map_from_base, ctx.geometry, config.clear_radius_m)
    if near is not None:
        dv.clear_since_s = None
        return Outcome(
            cy.speed_cap_mps,
            f"drop-off: waiting, pedestrian track {near[0]} {near[1]:.1f} m from the door side",
        )
    if dv.clear_since_s is None:
        dv.clear_since_s = t_s
    standing = t_s - dv.halted_since_s
    if standing < config.wait_s or t_s - dv.clear_since_s < config.clear_for_s:
        return Outcome(cy.speed_cap_mps, f"drop-off: standing {standing:.1f} s of {config.wait_s:.1f} s")
    ctx.mission.drop_off_served()
    why = f"drop-off served after {standing:.1f} s standing, no pedestrian near the door"
    mem.enter(BehaviourState.MERGING, t_s, why)
    mem.stop.merge_from_s_m = inp.route_s_m
    return Outcome(cy.speed_cap_mps, why)
