"""Passing a stationary obstacle that blocks the lane, by the adjacent lane, when the map and traffic allow.

aUToronto's planner (7.1) keeps a temporal record of static obstacles and goes around them into a
sibling lanelet with a lattice; Snow Lion's behaviour planner truncates the path at a static obstacle
it cannot pass. This rule decides *whether* to pass; the offset planner
(:mod:`lastmile.planning.pass_path`) decides *how*. A pass is ordered only when all of these hold:

- the obstacle blocks the lane (no in-lane nudge keeps ``clearance_m``), is not a pedestrian, cyclist
  or animal, and has stood still (below ``stationary_speed_mps``) for ``stationary_s``;
- it is not waiting in traffic: no stop line, crosswalk or junction within ``control_clear_m`` ahead of
  it, and no other road user in the lane within ``queue_gap_m`` ahead of it (a queue);
- the map lets the shuttle use the lane on its left over the whole manoeuvre: every route record of it
  is plain road or a bus bay (no junction, crosswalk or driveway), the lanelet's left boundary is a
  passable type (``passable_left_types``: broken lines, a virtual line), and the road surface is there;
- it can see enough: beyond the stretch used and ``oncoming_gap_m``, the rest of the sight distance
  (``sight_m``, less where the obstacle hides the oncoming lane: :meth:`PassRule.sight_m`) lets a road
  user not yet seen, coming at the speed limit, stop in time or arrive only after the manoeuvre;
- no track is in the adjacent lane over that stretch, and every track coming towards the shuttle there
  stays ``oncoming_gap_m`` beyond where the shuttle's front will be once back in its lane, over the
  manoeuvre's time plus ``time_margin_s`` (constant velocity), and that has held ``clear_for_s``;
- the front is ``min_start_gap_m`` or more behind the obstacle (room to steer out).

An obstacle the map, a queue or traffic control forbids passing is stopped for as any (the in-path
test). Where only traffic or the standing clock forbids it, the shuttle waits ``wait_gap_m`` behind it
(room for the lateral move, a view past it) at the planner's look-out offset, and the checks are made
again every cycle. A pass not yet committed is called off as soon as a check fails; it is committed
once the shuttle is ``commit_d_m`` out of its lane or can no longer stop comfortably
``min_start_gap_m`` behind the obstacle, and is then finished (the in-path test still stops the
shuttle for anything on the planned path).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import PassRequest, StopReason
from lastmile.decision.pass_config import PassConfig
from lastmile.decision.stop_constraints import StopConstraint
from lastmile.hdmap.layers import SLayerDatabase

PLAIN_ROAD, BUS_BAY = 0, 3
"""``SLayerDatabase.road_type`` codes a pass may run over (junctions, crosswalks, driveways: not)."""


class PassPhase(Enum):
    """Where the rule is with the obstacle ahead."""

    NONE = "none"
    WAITING = "waiting"
    PASSING = "passing"


@dataclass(slots=True)
class PassMemory:
    """What the rule keeps between cycles."""

    phase: PassPhase = PassPhase.NONE
    standing_since_s: dict[int, float] = field(default_factory=dict)
    request: PassRequest | None = None
    why: str = ""
    clear_since_s: float | None = None


@dataclass(frozen=True, slots=True)
class PassInput:
    """The cycle as the rule sees it (the front's s and lap; the rear axle's lateral offset)."""

    t_s: float
    front_s_m: float
    route_d_m: float
    speed_mps: float
    obstacles: list[RouteObstacle]
    may_start: bool


class PassRule:
    """Decides each planning cycle whether to pass a stationary obstacle ahead (see the module)."""

    def __init__(
        self, layers: SLayerDatabase, geometry: VehicleGeometry, config: PassConfig, enabled: bool
    ) -> None:
        self.layers, self.geometry, self.config, self.enabled = layers, geometry, config, enabled
        self.memory = PassMemory()
        self._fragments: set[int] = set()  # the tracks of this cycle's blocker

    @property
    def phase(self) -> PassPhase:
        return self.memory.phase

    def step(self, inp: PassInput) -> tuple[PassRequest | None, list[StopConstraint]]:
        """The pass to plan this cycle (None: stay in the lane) and the stop points it adds."""
        mem, c = self.memory, self.config
        self._update_standing(inp)
        if not self.enabled:
            return None, []
        if mem.phase is PassPhase.PASSING and mem.request is not None and mem.request.committed:
            return self._continue(inp), []
        blocker = self._blocker(inp)
        if blocker is None:
            mem.phase, mem.request, mem.why, mem.clear_since_s = PassPhase.NONE, None, "", None
            return None, []
        why = self._static_why_not(inp, blocker)
        if why is None and mem.phase is not PassPhase.PASSING:
            why = self._too_close(inp, blocker)
        if why is not None:  # never to be passed: stopped for as any obstacle (the in-path test)
            mem.phase, mem.request, mem.why, mem.clear_since_s = PassPhase.NONE, None, why, None
            return None, []
        why = self._not_yet_standing(inp, blocker)
        if why is not None:  # it may be passed once it has stood long enough: wait back, in the lane
            mem.phase, mem.request, mem.why, mem.clear_since_s = PassPhase.WAITING, None, why, None
            return None, self._wait(inp, blocker)
        lookout = self._request(blocker, inp)
        why = self._dynamic_why_not(inp, blocker)
        if why is None and mem.phase is not PassPhase.PASSING:
            why = self._clear_long_enough(inp)
        else:
            mem.clear_since_s = None if why is not None else mem.clear_since_s
        if why is None and inp.may_start:
            # Committed once out of the lane, or once past the last point from which the shuttle could
            # still stop comfortably at the waiting point (after that, calling the pass off would leave
            # it standing too close behind the obstacle to steer out ever again).
            committed = inp.route_d_m > c.commit_d_m or self._past_no_return(inp, blocker)
            mem.phase, mem.why = PassPhase.PASSING, "passing"
            mem.request = dataclasses.replace(lookout, approved=True, committed=committed)
            return mem.request, []
        mem.phase, mem.request, mem.why = PassPhase.WAITING, None, why or "not in normal driving"
        # Waiting to pass: hold at the left of the lane to see past the obstacle.
        return (lookout if inp.may_start else None), self._wait(inp, blocker)

    def _clear_long_enough(self, inp: PassInput) -> str | None:
        mem, c = self.memory, self.config
        if mem.clear_since_s is None:
            mem.clear_since_s = inp.t_s
        if inp.t_s - mem.clear_since_s < c.clear_for_s:
            return "adjacent lane not yet clear for long enough"
        return None

    def _wait_point_s_m(self, inp: PassInput, o: RouteObstacle) -> float:
        return inp.front_s_m + o.ds_m - o.length_m / 2.0 - self.config.wait_gap_m

    def _past_no_return(self, inp: PassInput, o: RouteObstacle) -> bool:
        """The shuttle can no longer stop comfortably ``min_start_gap_m`` behind the obstacle, the
        closest a pass can be begun from."""
        c = self.config
        last_start = inp.front_s_m + o.ds_m - o.length_m / 2.0 - c.min_start_gap_m
        room = last_start - inp.front_s_m
        return room <= inp.speed_mps**2 / (2.0 * c.wait_decel_mps2) + 0.5

    def _too_close(self, inp: PassInput, o: RouteObstacle) -> str | None:
        """A pass not yet begun needs the front at least ``min_start_gap_m`` behind the obstacle."""
        if o.ds_m - o.length_m / 2.0 < self.config.min_start_gap_m:
            return "too close behind the obstacle to steer out"
        return None

    # --- the obstacle ---------------------------------------------------------------------------
    def _update_standing(self, inp: PassInput) -> None:
        c, since = self.config, self.memory.standing_since_s
        seen: dict[int, float] = {}
        for o in inp.obstacles:
            # Hysteresis: a standing track's speed estimate wanders (0.1-0.4 m/s for a radar-tracked
            # parked car as the shuttle closes in); only a clear move restarts its clock.
            if o.track_id in since and o.speed_mps < c.moving_speed_mps:
                seen[o.track_id] = since[o.track_id]
            elif o.speed_mps < c.stationary_speed_mps:
                seen[o.track_id] = inp.t_s
        self.memory.standing_since_s = seen

    def _in_lane(self, o: RouteObstacle, s_m: float) -> bool:
        """The obstacle's footprint overlaps the shuttle's lane at route s."""
        i = self.layers.record_index(s_m)
        left, right = float(self.layers.lane_left_d_m[i]), float(self.layers.lane_right_d_m[i])
        return o.d_m - o.width_m / 2.0 < left and o.d_m + o.width_m / 2.0 > right

    def _blocker(self, inp: PassInput) -> RouteObstacle | None:
        """The nearest standing obstacle ahead that leaves no room to pass inside the lane."""
        c, half = self.config, self.geometry.width_m / 2.0
        best: RouteObstacle | None = None
        for o in inp.obstacles:
            if o.ds_m + o.length_m / 2.0 < 0.0 or o.ds_m > c.lookahead_m or o.cls.vulnerable:
                continue
            if o.track_id not in self.memory.standing_since_s:
                continue  # moving: a lead to follow, not an obstacle to pass
            s = inp.front_s_m + o.ds_m
            if not self._in_lane(o, s):
                continue
            left = float(self.layers.lane_left_d_m[self.layers.record_index(s)])
            if o.d_m + o.width_m / 2.0 + c.clearance_m + 2.0 * half < left:
                continue  # room on its left inside the lane: the in-lane nudge passes it
            if best is None or o.ds_m < best.ds_m:
                best = o
        return None if best is None else self._with_fragments(inp, best)

    def _with_fragments(self, inp: PassInput, first: RouteObstacle) -> RouteObstacle:
        """``first`` grown over the standing tracks in the lane that touch it along the road: LiDAR
        clusters split a parked car into several tracks (four over 4.5 m, raw perception), which are
        one obstacle to pass, not a queue. The result keeps ``first``'s track id."""
        c = self.config
        lo, hi = first.ds_m - first.length_m / 2.0, first.ds_m + first.length_m / 2.0
        left, right = first.d_m + first.width_m / 2.0, first.d_m - first.width_m / 2.0
        self._fragments = {first.track_id}
        for o in sorted(inp.obstacles, key=lambda k: k.ds_m):
            if o.track_id in self._fragments or o.cls.vulnerable:
                continue
            if o.track_id not in self.memory.standing_since_s or not self._in_lane(o, inp.front_s_m + o.ds_m):
                continue
            o_lo, o_hi = o.ds_m - o.length_m / 2.0, o.ds_m + o.length_m / 2.0
            if o_lo > hi + c.fragment_gap_m or o_hi < lo - c.fragment_gap_m:
                continue
            lo, hi = min(lo, o_lo), max(hi, o_hi)
            left, right = max(left, o.d_m + o.width_m / 2.0), min(right, o.d_m - o.width_m / 2.0)
            self._fragments.add(o.track_id)
        ds = 0.5 * (lo + hi)
        return dataclasses.replace(
            first,
            s_m=first.s_m + ds - first.ds_m,
            ds_m=ds,
            d_m=0.5 * (left + right),
            length_m=hi - lo,
            width_m=left - right,
        )

    def _static_why_not(self, inp: PassInput, o: RouteObstacle) -> str | None:
        """Why this obstacle may not be passed at all (None: it may, traffic permitting)."""
        c = self.config
        front_of_it = inp.front_s_m + o.ds_m + o.length_m / 2.0
        if self._traffic_control_ahead(front_of_it):
            return "obstacle waits at a stop line, crosswalk or junction"
        if self._queue_ahead(inp, o):
            return "obstacle is in a queue"
        rear_of_it = inp.front_s_m + o.ds_m - o.length_m / 2.0
        start = max(inp.front_s_m, rear_of_it - c.wait_gap_m)
        return self._map_forbids(inp, o, start, self._zone_end_front_s_m(inp, o))

    def _not_yet_standing(self, inp: PassInput, o: RouteObstacle) -> str | None:
        since = self.memory.standing_since_s.get(o.track_id)
        if since is None or inp.t_s - since < self.config.stationary_s:
            return "obstacle not standing long enough"
        return None

    def _dynamic_why_not(self, inp: PassInput, o: RouteObstacle) -> str | None:
        """Why traffic forbids the pass now (None: clear)."""
        end = self._zone_end_front_s_m(inp, o)
        if not self._unseen_traffic_can_stop(inp, o, end):
            return "not enough sight distance for the pass"
        return self._traffic_forbids(inp, o, end)

    def sight_m(self, inp: PassInput, o: RouteObstacle) -> float:
        """How far along the adjacent lane's centre the front sensor sees past the obstacle: the ray
        from the front (at the shuttle's offset) over the obstacle's near left corner meets that line
        (``sight_m`` at most; the obstacle hides the rest from a shuttle standing behind it)."""
        c, lay = self.config, self.layers
        rear_of_it = o.ds_m - o.length_m / 2.0
        left_edge = o.d_m + o.width_m / 2.0
        centre = float(lay.lane_left_d_m[lay.record_index(inp.front_s_m)]) + c.adjacent_width_m / 2.0
        if rear_of_it <= 0.0:
            return 0.0  # beside it: a pass is not begun from here
        if inp.route_d_m >= left_edge - 0.05:
            return c.sight_m
        return min(c.sight_m, rear_of_it * (centre - inp.route_d_m) / (left_edge - inp.route_d_m))

    def _traffic_control_ahead(self, s_m: float) -> bool:
        c, lay = self.config, self.layers
        probe = np.arange(s_m, s_m + c.control_clear_m, lay.step_m)
        types = lay.road_type[lay.record_indices(probe)]
        if bool(np.any((types != PLAIN_ROAD) & (types != BUS_BAY))):
            return True
        route = lay.centerline
        return any(0.0 <= route.ds_m(s_m, sl.s_m) < c.control_clear_m for sl in lay.stop_lines)

    def _queue_ahead(self, inp: PassInput, o: RouteObstacle) -> bool:
        c = self.config
        front = o.ds_m + o.length_m / 2.0
        for other in inp.obstacles:
            if other.track_id in self._fragments:
                continue
            gap = other.ds_m - other.length_m / 2.0 - front
            if 0.0 <= gap < c.queue_gap_m and self._in_lane(other, inp.front_s_m + other.ds_m):
                return True
        return False

    # --- the manoeuvre ------------------------------------------------------------------------------
    def _zone_end_front_s_m(self, inp: PassInput, o: RouteObstacle) -> float:
        """Route s of the front once the shuttle is back in its lane after passing ``o``."""
        c, g = self.config, self.geometry
        back_in_rear_axle = inp.front_s_m + o.ds_m + o.length_m / 2.0 + g.rear_overhang_m + c.return_gap_m
        return back_in_rear_axle + c.transition_m + g.front_from_rear_axle_m

    def _unseen_traffic_can_stop(self, inp: PassInput, o: RouteObstacle, end_front_s_m: float) -> bool:
        """A road user the stack cannot see yet (beyond ``sight_m``) coming at the speed limit stops
        before the shuttle's way back into its lane, ``oncoming_gap_m`` short (reaction
        ``oncoming_reaction_s``, then ``oncoming_decel_mps2``), or arrives only after the manoeuvre."""
        c = self.config
        spare = self.sight_m(inp, o) - (end_front_s_m - inp.front_s_m) - c.oncoming_gap_m
        if spare < 0.0:
            return False
        v = float(self.layers.speed_limit_mps[self.layers.record_indices(np.array([end_front_s_m]))[0]])
        stopping = v * c.oncoming_reaction_s + v * v / (2.0 * c.oncoming_decel_mps2)
        arrives_after = spare >= v * (self._manoeuvre_s(end_front_s_m - inp.front_s_m, inp.speed_mps))
        return stopping <= spare or arrives_after

    def _manoeuvre_s(self, distance_m: float, speed_mps: float) -> float:
        """Time to drive ``distance_m`` from ``speed_mps``, accelerating to the pass speed."""
        c = self.config
        v0, v1 = min(speed_mps, c.pass_speed_mps), c.pass_speed_mps
        ramp_s = (v1 - v0) / c.accel_mps2
        ramp_m = (v1 * v1 - v0 * v0) / (2.0 * c.accel_mps2)
        if ramp_m >= distance_m:
            return (math.sqrt(v0 * v0 + 2.0 * c.accel_mps2 * distance_m) - v0) / c.accel_mps2
        return ramp_s + (distance_m - ramp_m) / v1

    def _map_forbids(self, inp: PassInput, o: RouteObstacle, start_m: float, end_m: float) -> str | None:
        c, lay, hd = self.config, self.layers, self.layers.hdmap
        rec = np.unique(lay.record_indices(np.arange(start_m, end_m + lay.step_m, lay.step_m)))
        types = lay.road_type[rec]
        if bool(np.any((types != PLAIN_ROAD) & (types != BUS_BAY))):
            return "junction or crosswalk in the pass zone"
        for lid in np.unique(lay.lanelet_id[rec]).tolist():
            info = hd.lanelets.get(int(lid))
            if info is None or info.left_type not in c.passable_left_types:
                kind = "unknown" if info is None else info.left_type or "unmapped"
                return f"lane boundary on the left not passable ({kind})"
        need_d = o.d_m + o.width_m / 2.0 + c.clearance_m + self.geometry.width_m
        s = lay.s_m[rec]
        xy = lay.centerline.points_at(s)
        heading = np.array([lay.centerline.heading_at(float(v)) for v in s])
        normal = np.c_[-np.sin(heading), np.cos(heading)]
        probes = np.vstack([xy + normal * float(d) for d in (lay.lane_left_d_m[rec].min() + 0.3, need_d)])
        if not bool(np.all(hd.is_drivable(probes))):
            return "no road surface on the left for the pass"
        return None

    def _traffic_forbids(self, inp: PassInput, o: RouteObstacle, end_front_s_m: float) -> str | None:
        """Tracks in the adjacent lane over the stretch, or coming too soon (None: clear)."""
        c = self.config
        lay = self.layers
        duration = self._manoeuvre_s(end_front_s_m - inp.front_s_m, inp.speed_mps) + c.time_margin_s
        for other in inp.obstacles:
            if other.track_id in self._fragments:
                continue
            s = inp.front_s_m + other.ds_m
            left = float(lay.lane_left_d_m[lay.record_index(s)])
            near = other.d_m + other.width_m / 2.0 > left - 0.5
            if not near or other.d_m - other.width_m / 2.0 > left + c.adjacent_width_m:
                continue
            near_end = other.ds_m - other.length_m / 2.0  # from the front, along the route
            if near_end < -self.geometry.length_m:
                continue  # behind the shuttle
            if other.v_s_mps >= -c.stationary_speed_mps and near_end <= end_front_s_m - inp.front_s_m:
                return f"track {other.track_id} in the adjacent lane over the pass"
            reach = near_end + other.v_s_mps * duration  # v_s < 0: coming towards the shuttle
            if other.v_s_mps < 0.0 and reach < end_front_s_m - inp.front_s_m + c.oncoming_gap_m:
                return f"oncoming track {other.track_id} within the manoeuvre's reach"
        return None

    def _request(self, o: RouteObstacle, inp: PassInput) -> PassRequest:
        """The pass around ``o``, not yet approved (the planner holds the look-out offset)."""
        c, lay = self.config, self.layers
        s = inp.front_s_m + o.ds_m
        left = float(lay.lane_left_d_m[lay.record_index(s)])
        return PassRequest(
            track_id=o.track_id,
            start_s_m=s - o.length_m / 2.0,
            end_s_m=s + o.length_m / 2.0,
            left_d_m=o.d_m + o.width_m / 2.0,
            max_d_m=left + c.adjacent_width_m,
            lookout_d_m=max(0.0, left - self.geometry.width_m / 2.0 - c.lookout_margin_m),
            wait_s_m=s - o.length_m / 2.0 - c.wait_gap_m,
            approved=False,
        )

    def _continue(self, inp: PassInput) -> PassRequest | None:
        """A begun pass: keep the obstacle's extent (grown if seen larger) until the shuttle is back."""
        mem, c, g = self.memory, self.config, self.geometry
        req = mem.request
        assert req is not None
        for o in inp.obstacles:
            if o.track_id == req.track_id:
                s = inp.front_s_m + o.ds_m
                req = dataclasses.replace(
                    req,
                    start_s_m=min(req.start_s_m, s - o.length_m / 2.0),
                    end_s_m=max(req.end_s_m, s + o.length_m / 2.0),
                    left_d_m=max(req.left_d_m, o.d_m + o.width_m / 2.0),
                    committed=True,
                )
        back_in_front_s = req.end_s_m + g.rear_overhang_m + c.return_gap_m + c.transition_m
        back_in_front_s += g.front_from_rear_axle_m
        route = self.layers.centerline
        if route.ds_m(back_in_front_s, inp.front_s_m) > 0.0 and abs(inp.route_d_m) < c.commit_d_m:
            mem.phase, mem.request, mem.why = PassPhase.NONE, None, "passed"
            return None
        mem.request = req
        return req

    def _wait(self, inp: PassInput, o: RouteObstacle) -> list[StopConstraint]:
        """Stop ``wait_gap_m`` behind the obstacle; a shuttle already past that point (a pass called
        off, the point moved with the obstacle's track) stops where it comfortably can at
        ``wait_decel_mps2``, as long as that is ``min_start_gap_m`` or more behind the obstacle (else
        the in-path test's stop point alone holds it, 3 m behind, where it can no longer steer out)."""
        c = self.config
        stop = self._wait_point_s_m(inp, o)
        soonest = inp.front_s_m + inp.speed_mps**2 / (2.0 * c.wait_decel_mps2)
        if stop < soonest:
            stop = soonest
            last_start = inp.front_s_m + o.ds_m - o.length_m / 2.0 - c.min_start_gap_m
            if stop > last_start:
                return []
        return [
            StopConstraint(
                stop, "waiting to pass", o.track_id, emergency_ok=False, reason=StopReason.OBSTACLE
            )
        ]
