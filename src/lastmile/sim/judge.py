"""The simulator's referee: collisions, rule violations, stops served, from ground truth only.

Nothing here reaches the stack; its verdicts go to the run log as events.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.geometry import (
    PreparedPolygon,
    convex_polygons_overlap,
    point_in_polygon,
    rectangle_corners_m,
)
from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.run_events import EventKind
from lastmile.hdmap.model import DRIVABLE_SUBTYPES
from lastmile.sim.arbiter import EGO_ID
from lastmile.sim.give_way_referee import GiveWayReferee
from lastmile.sim.passengers import PassengerModel, StopVisit
from lastmile.sim.traffic_signals import SignalController
from lastmile.sim.world import StopLineTruth, World

BODY_SIDE_SAMPLES = 24
"""Points along the shuttle's right side (corners included, ~0.2 m apart) whose least gap to the curb is
the body's gap at a stop."""

Event = tuple[float, EventKind, dict[str, object]]


@dataclass(slots=True)
class JudgeConfig:
    """Tolerances of the referee.

    Attributes:
        speed_tolerance_mps: speed over the limit that counts, held for ``speed_hold_s``.
        stop_speed_mps: below this the shuttle has come to a stop (stop lines, stops).
        ttc_log_s: time-to-collision below which a ``min_ttc`` event is logged.
        wrong_way_gate_d_m: the wrong-way rule looks only while the shuttle's centre is this far left
            of its route (it cannot be in the opposite lane otherwise; keeps the map query off most ticks).
        obstruction_reach_m: a stationary car or object in the shuttle's own direction of travel within
            this of its centre makes driving in the opposite lane legal (passing an obstruction)...
        passable_lines: ... where the line between the lanes is one of these (crossing a solid line
            is a violation even then).
    """

    speed_limit_mps: float = 20.0 / 3.6
    wrong_way_gate_d_m: float = 1.0
    obstruction_reach_m: float = 30.0
    passable_lines: tuple[str, ...] = ("line_thin:dashed", "line_thick:dashed", "virtual")
    speed_tolerance_mps: float = 0.5
    speed_hold_s: float = 1.0
    stop_speed_mps: float = 0.2
    ttc_log_s: float = 3.0


@dataclass(slots=True)
class _LineState:
    stopped: bool = False
    last_along_m: float | None = None


@dataclass
class Judge:
    """Watches the world each tick and emits events."""

    world: World
    passengers: PassengerModel
    service_route: Polyline
    config: JudgeConfig = field(default_factory=JudgeConfig)
    signals: SignalController | None = None
    map_speed_limits: bool = False
    """Judge speed against the limit the map states for the lanelet under the shuttle (the route file's
    ``unmapped_speed_limit_mps`` where it states none) instead of ``config.speed_limit_mps``."""
    unmapped_speed_limit_mps: float | None = None
    events: list[Event] = field(default_factory=list)
    _colliding: set[int] = field(default_factory=set)
    _line_state: dict[int, _LineState] = field(default_factory=dict)
    _speeding_since: float | None = None
    _speeding_logged: bool = False
    _off_road: bool = False
    _crosswalk_flagged: set[int] = field(default_factory=set)
    _route_s: float = 0.0
    _route_s_total: float = 0.0
    _loops: int = 0
    _approached: dict[str, int] = field(default_factory=dict)
    _ttc_min_logged: float = math.inf
    _crosswalk_polys: list[tuple[int, PreparedPolygon]] = field(default_factory=list)
    _route_d: float = 0.0
    _wrong_way: bool = False

    def __post_init__(self) -> None:
        s = self.world.ego.state
        self._route_s = self.service_route.project(s.x_m, s.y_m).s_m
        self._stop_s = {
            st.id: (
                self.service_route.project(*st.curb.point_at(0.0)[:2]).s_m,
                self.service_route.project(*st.curb.point_at(st.curb.length_m)[:2]).s_m,
            )
            for st in self.passengers.stops.values()
        }
        self._crosswalk_polys = [(cw.id, PreparedPolygon(cw.polygon)) for cw in self.world.hdmap.crosswalks]
        self._give_way = GiveWayReferee(self.world.hdmap, self.service_route)

    @property
    def route_s_m(self) -> float:
        return self._route_s

    def emit(self, kind: EventKind, **data: object) -> None:
        self.events.append((round(self.world.t_s, 6), kind, data))

    def step(self) -> None:
        self._collisions()
        self._stop_lines()
        self._stop_signs()
        self._yield_lines()
        self._signal_lines()
        self._crosswalks()
        self._speed()
        self._drivable()
        self._progress()
        self._wrong_way_rule()
        self._ttc()

    # --- collisions ------------------------------------------------------------------------
    def _collisions(self) -> None:
        w = self.world
        ex, ey = w.ego_centre()
        s = w.ego.state
        reach = 0.5 * math.hypot(w.geometry.length_m, w.geometry.width_m)
        ego_box: np.ndarray | None = None
        now_touching: set[int] = set()
        for a in w.agents:
            if not a.active or math.hypot(a.x_m - ex, a.y_m - ey) > reach + a.radius_m:
                continue
            if ego_box is None:
                ego_box = w.ego_corners()
            if convex_polygons_overlap(
                ego_box, rectangle_corners_m(a.x_m, a.y_m, a.yaw_rad, a.length_m, a.width_m)
            ):
                now_touching.add(a.id)
                if a.id not in self._colliding:
                    along = (a.x_m - ex) * math.cos(s.yaw_rad) + (a.y_m - ey) * math.sin(s.yaw_rad)
                    # The shuttle is at fault when it moves into something ahead of it; a standing
                    # shuttle struck, or one hit from behind, is not.
                    at_fault = s.speed_mps > 0.3 and along > 0.0
                    self.emit(
                        EventKind.COLLISION,
                        agent_id=a.id,
                        agent_class=a.cls.name.lower(),
                        at_fault=at_fault,
                        ego_speed_mps=round(s.speed_mps, 3),
                    )
        self._colliding = now_touching

    # --- traffic signals -----------------------------------------------------------------------
    def _signal_lines(self) -> None:
        """Crossing a signal's stop line while it shows red is a violation; flashing red is a stop sign
        (legal after a full stop within 4 m of the line). Each crossing is logged with the state shown."""
        if self.signals is None:
            return
        w = self.world
        signal_of = {sl.id: sl.signal_id for sl in w.hdmap.stop_lines if sl.signal_id is not None}
        signalled = [line for line in w.stop_lines if line.id in signal_of]
        for line, st, standing, crossed in self._line_passages(signalled):
            sig = signal_of[line.id]
            if standing:
                st.stopped = True
            if crossed:
                shown = self.signals.state(sig, w.t_s).name.lower()
                flashing_stop_ok = self.signals.stop_then_go() and st.stopped
                if self.signals.must_stop(sig, w.t_s) and not flashing_stop_ok:
                    self.emit(
                        EventKind.RULE_VIOLATION,
                        rule="red_light",
                        detail=f"ran signal {sig} at stop line {line.id} ({shown})",
                    )
                self.emit(
                    EventKind.SIGNAL_ENTRY,
                    stop_line_id=line.id,
                    signal_id=sig,
                    shown=shown,
                    stopped_before=st.stopped,
                )
                st.stopped = False

    def _line_passages(
        self, lines: list[StopLineTruth]
    ) -> Iterator[tuple[StopLineTruth, _LineState, bool, bool]]:
        """For each stop line the shuttle is approaching: (line, its state, standing at it now, crossed it
        this tick). The caller decides what standing means (arrival, a full stop); the distance is
        remembered for the next tick once the caller is done with the line."""
        w = self.world
        speed = w.ego.state.speed_mps
        for line in lines:
            along = w.ego_stop_line_distance(line)
            st = self._line_state.setdefault(line.id, _LineState())
            if along is None:
                st.stopped, st.last_along_m = False, None
                continue
            standing = -1.0 <= along <= 4.0 and speed < self.config.stop_speed_mps
            crossed = st.last_along_m is not None and st.last_along_m > 0.0 >= along
            yield line, st, standing, crossed
            st.last_along_m = along

    # --- stop lines and right of way -------------------------------------------------------------
    def _stop_lines(self) -> None:
        w = self.world
        all_way = [line for line in w.stop_lines if line.all_way_stop_id is not None]
        for line, st, standing, crossed in self._line_passages(all_way):
            arbiter = w.arbiter(line.id)
            if standing:
                if not st.stopped:
                    arbiter.arrive(EGO_ID, line.id, w.t_s)
                st.stopped = True
            if crossed:
                if not st.stopped:
                    self.emit(EventKind.RULE_VIOLATION, rule="stop_line", detail=f"ran stop line {line.id}")
                owed = arbiter.earlier_than(EGO_ID) if EGO_ID in arbiter.queue else list(arbiter.queue)
                inside = arbiter.box_occupied_by - {EGO_ID}
                order_ok = not owed and not inside
                self.emit(
                    EventKind.INTERSECTION_ENTRY,
                    stop_line_id=line.id,
                    order_ok=order_ok,
                    waiting_before=len(owed),
                )
                if not order_ok:
                    self.emit(
                        EventKind.RULE_VIOLATION,
                        rule="right_of_way",
                        detail=f"entered with {len(owed)} earlier arrivals waiting, {len(inside)} inside",
                    )
                arbiter.enter(EGO_ID)
                st.stopped = False

    def _stop_signs(self) -> None:
        """A two-way stop's line (a stop sign outside an all-way stop or a signal) crossed without a
        full stop within 4 m of it (``_line_passages``) is a violation: StVO Zeichen 206, UVC 11-703."""
        w = self.world
        signalled = {sl.id for sl in w.hdmap.stop_lines if sl.signal_id is not None}
        two_way = [
            line
            for line in w.stop_lines
            if line.stop_sign_id is not None and line.all_way_stop_id is None and line.id not in signalled
        ]
        for line, st, standing, crossed in self._line_passages(two_way):
            if standing:
                st.stopped = True
            if crossed:
                if not st.stopped:
                    self.emit(
                        EventKind.RULE_VIOLATION,
                        rule="stop_sign",
                        detail=f"rolled through stop sign line {line.id}",
                    )
                st.stopped = False

    def _yield_lines(self) -> None:
        """Give-way lines and two-way stops: each passage, and a failure to yield to priority traffic
        (``give_way_referee``)."""
        if not self._give_way.junctions:
            return
        w = self.world
        for kind, data in self._give_way.step(w.t_s, w.ego_front(), w.ego.state.speed_mps, w.agents):
            self.emit(kind, **data)

    def _crosswalks(self) -> None:
        w = self.world
        box = w.ego_corners().tolist()
        for cw_id, poly in self._crosswalk_polys:
            touching = any(poly.contains(x, y) for x, y in box)
            if not touching:
                self._crosswalk_flagged.discard(cw_id)
                continue
            if cw_id in self._crosswalk_flagged or w.ego.state.speed_mps < 0.3:
                continue
            ex, ey = w.ego_centre()
            for a in w.agents:
                if (
                    a.active
                    and a.cls == ObjectClass.PEDESTRIAN
                    and poly.contains(a.x_m, a.y_m)
                    and math.hypot(a.x_m - ex, a.y_m - ey) < 6.0
                ):
                    self.emit(
                        EventKind.RULE_VIOLATION,
                        rule="crosswalk_yield",
                        detail=f"crosswalk {cw_id}, pedestrian {a.id}",
                    )
                    self._crosswalk_flagged.add(cw_id)
                    break

    def _limit_mps(self) -> float:
        """The speed limit the referee applies where the shuttle is."""
        if not self.map_speed_limits:
            return self.config.speed_limit_mps
        x, y = self.world.ego_centre()
        lid = self.world.hdmap.lanelet_at(x, y)
        mapped = self.world.hdmap.lanelets[lid].speed_limit_mps if lid is not None else math.nan
        if math.isfinite(mapped):
            return float(mapped)
        if self.unmapped_speed_limit_mps is not None:
            return self.unmapped_speed_limit_mps
        return self.config.speed_limit_mps  # off the map: the drivable-area rule judges that

    def _speed(self) -> None:
        w, c = self.world, self.config
        if w.ego.state.speed_mps > self._limit_mps() + c.speed_tolerance_mps:
            if self._speeding_since is None:
                self._speeding_since = w.t_s
            if not self._speeding_logged and w.t_s - self._speeding_since >= c.speed_hold_s:
                self.emit(
                    EventKind.RULE_VIOLATION, rule="speed_limit", detail=f"{w.ego.state.speed_mps:.2f} m/s"
                )
                self._speeding_logged = True
        else:
            self._speeding_since, self._speeding_logged = None, False

    def _drivable(self) -> None:
        w = self.world
        off = not bool(np.all(w.hdmap.is_drivable(w.ego_corners())))
        if off and not self._off_road:
            self.emit(
                EventKind.RULE_VIOLATION, rule="drivable_area", detail="a corner of the shuttle left the road"
            )
        self._off_road = off

    def _wrong_way_rule(self) -> None:
        """Driving in a lane of the opposite direction is a violation, unless the shuttle is passing a
        stationary obstruction in its own lane across a passable line (one event per episode)."""
        if self._route_d < self.config.wrong_way_gate_d_m:
            self._wrong_way = False
            return
        lane = self._lane_against_ego()
        if lane is None:
            self._wrong_way = False
            return
        if self._wrong_way:
            return
        self._wrong_way = True
        line = self.world.hdmap.lanelets[lane].left_type
        if line not in self.config.passable_lines:
            self.emit(
                EventKind.RULE_VIOLATION, rule="wrong_way", detail=f"crossed a {line or 'unmapped'} line"
            )
        elif not self._obstruction_nearby():
            self.emit(EventKind.RULE_VIOLATION, rule="wrong_way", detail="no stationary obstruction to pass")

    def _lane_against_ego(self) -> int | None:
        """The lanelet under the shuttle's centre when it runs against the shuttle's heading (None: it
        does not, or a lanelet in the shuttle's direction overlaps there, as inside a junction)."""
        x, y = self.world.ego_centre()
        yaw = self.world.ego.state.yaw_rad
        against: int | None = None
        for lid, info in self.world.hdmap.lanelets.items():
            if info.subtype not in DRIVABLE_SUBTYPES or not point_in_polygon(x, y, info.polygon()):
                continue
            along = info.centerline.heading_at(info.centerline.project(x, y).s_m)
            if math.cos(along - yaw) > 0.0:
                return None
            against = lid
        return against

    def _obstruction_nearby(self) -> bool:
        """A standing car or object within reach, in a lane of the shuttle's direction."""
        w, c = self.world, self.config
        for a in w.agents:
            if not a.active or a.cls.vulnerable or a.speed_mps > c.stop_speed_mps:
                continue
            if w.distance_to_ego_m(a.x_m, a.y_m) > c.obstruction_reach_m:
                continue
            lid = w.hdmap.lanelet_at(a.x_m, a.y_m)
            if lid is None:
                continue
            cl = w.hdmap.lanelets[lid].centerline
            if math.cos(cl.heading_at(cl.project(a.x_m, a.y_m).s_m) - w.ego.state.yaw_rad) > 0.0:
                return True
        return False

    @property
    def off_road(self) -> bool:
        return self._off_road

    # --- progress, loops, stops ------------------------------------------------------------------
    def _progress(self) -> None:
        w = self.world
        s = w.ego.state
        f = self.service_route.project(s.x_m, s.y_m, hint_s_m=self._route_s, window_m=10.0)
        length = self.service_route.length_m
        ds = self.service_route.ds_m(self._route_s, f.s_m)
        self._route_d = f.d_m
        if abs(f.d_m) < 8.0:
            self._route_s_total += ds
            self._route_s = f.s_m
        loops = int(self._route_s_total // length)
        if loops > self._loops:
            self._loops = loops
            self.emit(EventKind.LOOP_COMPLETED, loop=loops)
        # A stop counts as missed when riders waited there as the shuttle came within 40 m and it
        # drove past the platform without opening the door.
        for stop_id, (s0, s1) in self._stop_s.items():
            to_start = (s0 - self._route_s) % length
            past_end = (self._route_s - s1) % length
            if 30.0 < to_start < 40.0 and stop_id not in self._approached:
                self._approached[stop_id] = len(self.passengers.waiting[stop_id])
            elif 0.5 < past_end < 5.0 and stop_id in self._approached:
                waited = self._approached.pop(stop_id)
                if waited and not self._served_recently(stop_id):
                    self.emit(EventKind.STOP_MISSED, stop_id=stop_id, waiting=waited)

    def _served_recently(self, stop_id: str) -> bool:
        for t, kind, data in reversed(self.events):
            if self.world.t_s - t > 240.0:
                return False
            if kind == "stop_served" and data.get("stop_id") == stop_id:
                return True
        return False

    def stop_at(self) -> str | None:
        """The stop whose platform the shuttle's door is beside, if any."""
        w = self.world
        s, g = w.ego.state, w.geometry
        door_along = g.length_m / 2.0 - g.rear_overhang_m
        dx = s.x_m + door_along * math.cos(s.yaw_rad) + (g.width_m / 2.0) * math.sin(s.yaw_rad)
        dy = s.y_m + door_along * math.sin(s.yaw_rad) - (g.width_m / 2.0) * math.cos(s.yaw_rad)
        for stop in self.passengers.stops.values():
            f = stop.curb.project(dx, dy)
            if -4.0 <= f.s_m <= stop.curb.length_m + 4.0 and 0.0 <= f.d_m < 1.5:
                return stop.id
        return None

    def open_visit(self, stop_id: str) -> StopVisit:
        """Measure the pull-over when the door starts opening at a stop.

        The curb gap is the door's: from the middle of the door on the shuttle's right side to the
        curb line, the step a rider takes. The body's least gap (every point of its right side, the
        corners included) is measured apart: beside a curved kerb a straight body's corners and its
        door are at different gaps, and only the body's least gap says whether it is clear of the
        kerb.
        """
        w = self.world
        stop = self.passengers.stops[stop_id]
        s, g = w.ego.state, w.geometry
        door_along = g.length_m / 2.0 - g.rear_overhang_m
        c, si = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
        half = g.width_m / 2.0
        along = np.append(
            np.linspace(-g.rear_overhang_m, g.length_m - g.rear_overhang_m, BODY_SIDE_SAMPLES), door_along
        )
        side_x = s.x_m + along * c + half * si
        side_y = s.y_m + along * si - half * c
        gaps = [stop.curb.project(float(x), float(y)).d_m for x, y in zip(side_x, side_y, strict=True)]
        door = stop.curb.project(s.x_m + door_along * c, s.y_m + door_along * si)
        lon_err = max(0.0, -door.s_m, door.s_m - stop.curb.length_m)
        return StopVisit(
            stop_id=stop_id,
            opened_s=w.t_s,
            curb_gap_m=round(gaps[-1], 4),
            body_gap_m=round(min(gaps), 4),
            longitudinal_error_m=round(lon_err, 4),
        )

    def _ttc(self) -> None:
        ttc, agent = self.time_to_collision()
        if ttc < self.config.ttc_log_s and ttc < self._ttc_min_logged - 0.05:
            self.emit(EventKind.MIN_TTC, ttc_s=round(ttc, 3), agent_id=agent)
            self._ttc_min_logged = ttc

    def time_to_collision(self) -> tuple[float, int]:
        """Constant-velocity time until the shuttle's front reaches something in its corridor.

        The other road user moves on at its velocity, sideways included: an oncoming car in its own
        lane drifts out of the line ahead of a shuttle swinging out of a bay, and a pedestrian
        stepping in is in the corridor when the front gets there. The corridor bends with the
        shuttle's present turn rate (a constant-curvature arc), as a safety driver watching the wheel
        judges it.
        """
        w = self.world
        s, g = w.ego.state, w.geometry
        fx, fy = w.ego_front()
        c, si = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
        curvature = s.yaw_rate_radps / s.speed_mps if s.speed_mps > 0.5 else 0.0
        best, who = math.inf, -1
        for a in w.agents:
            if not a.active:
                continue
            dx, dy = a.x_m - fx, a.y_m - fy
            along = dx * c + dy * si
            if along < -1.0 or along > 25.0:
                continue
            closing = s.speed_mps - (a.vx_mps * c + a.vy_mps * si)
            if closing <= 0.05:
                continue
            gap = max(0.0, along - a.length_m / 2.0)
            ttc = gap / closing
            drift = (-a.vx_mps * si + a.vy_mps * c) * ttc
            lateral = -dx * si + dy * c + drift - 0.5 * curvature * max(along, 0.0) ** 2
            if abs(lateral) > g.width_m / 2.0 + a.width_m / 2.0 + 0.2:
                continue
            if ttc < best:
                best, who = ttc, a.id
        return best, who
