"""Road users and their behaviours: cars on lanelet paths, a parked car, pedestrians, a goose.

Every agent exposes the same plain attributes (pose, speed, footprint, radar cross-section) so the
sensor models and the judge treat them alike; behaviours differ only in ``step``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.traffic_light_messages import LightState
from lastmile.hdmap.model import HDMap
from lastmile.sim.traffic_signals import SignalController

if TYPE_CHECKING:
    from lastmile.sim.world import World


CAR_LENGTH_M, CAR_WIDTH_M = 4.5, 1.8
"""A passenger car's footprint (a compact car's length and width)."""


@dataclass(slots=True, kw_only=True)
class Agent:
    """A simulated road user; (x_m, y_m) is the footprint centre, yaw from +x, speed along yaw."""

    id: int
    cls: ObjectClass
    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    length_m: float
    width_m: float
    rcs_dbsm: float
    active: bool = True

    @property
    def vx_mps(self) -> float:
        return self.speed_mps * math.cos(self.yaw_rad)

    @property
    def vy_mps(self) -> float:
        return self.speed_mps * math.sin(self.yaw_rad)

    @property
    def radius_m(self) -> float:
        return 0.5 * math.hypot(self.length_m, self.width_m)

    @property
    def steps_while_away(self) -> bool:
        """Whether the world keeps stepping this agent while it is off the map (to bring it back)."""
        return False

    def step(self, world: World, dt_s: float) -> None:
        """Advance the agent by ``dt_s``; the base agent stands still."""


@dataclass(slots=True, kw_only=True)
class StopLineOnPath:
    """An all-way-stop stop line as seen along a car's path."""

    s_m: float
    stop_line_id: int


@dataclass(slots=True, kw_only=True)
class SignalLineOnPath:
    """A traffic signal's stop line as seen along a car's path."""

    s_m: float
    signal_id: int


@dataclass(slots=True, kw_only=True)
class PathCar(Agent):
    """A car following a lanelet path with the intelligent driver model (IDM).

    It keeps a gap to whatever is ahead on its path (the shuttle included), stops at all-way-stop
    lines and leaves in arrival order as the world's arbiter allows. ``s_m`` is the path position of
    the footprint centre.
    """

    path: Polyline
    s_m: float
    desired_speed_mps: float
    stop_lines: list[StopLineOnPath] = field(default_factory=list)
    waiting_at: int | None = None
    cleared: set[int] = field(default_factory=set)
    despawn_at_end: bool = True
    max_accel_mps2: float = 1.2
    comfort_decel_mps2: float = 2.0
    min_gap_m: float = 2.5
    time_headway_s: float = 1.5
    signals: SignalController | None = None
    signal_lines: list[SignalLineOnPath] = field(default_factory=list)
    _signal_choice: tuple[int, str] | None = None  # (signal, "stop"/"go") once decided on a yellow
    _signal_stood_since_s: float | None = None
    _signal_cleared: int | None = None

    def obey_signals(self, signals: SignalController, hdmap: HDMap) -> None:
        """Stop at the signals on this car's path as a law-abiding driver does (see ``_signal_gap``)."""
        self.signals = signals
        self.signal_lines = []
        for sl in hdmap.stop_lines:
            if sl.signal_id is None:
                continue
            mid = np.asarray(sl.line, dtype=float).mean(axis=0)
            f = self.path.project(float(mid[0]), float(mid[1]))
            lanelet = hdmap.lanelets[sl.lanelet_id].centerline
            heading = lanelet.heading_at(lanelet.length_m - 0.1)
            if abs(f.d_m) < 2.0 and math.cos(self.path.heading_at(f.s_m) - heading) > 0.7:
                self.signal_lines.append(SignalLineOnPath(s_m=f.s_m, signal_id=sl.signal_id))

    def _signal_gap(self, t_s: float, gap_m: float, lead_mps: float) -> tuple[float, float]:
        """The gap to the next signal's stop line when the car must stop there: red, a yellow it can
        stop for comfortably, or a flashing red / dark signal (stop, then go after 1 s)."""
        if self.signals is None or not self.signal_lines:
            return gap_m, lead_mps
        best: tuple[float, SignalLineOnPath] | None = None
        for line in self.signal_lines:
            to_line = line.s_m - self.s_m - self.length_m / 2.0
            if self.path.closed:
                to_line = (to_line + 1.0) % self.path.length_m - 1.0
            if -1.0 < to_line < 60.0 and (best is None or to_line < best[0]):
                best = (to_line, line)
        if best is None:
            self._signal_choice, self._signal_stood_since_s, self._signal_cleared = None, None, None
            return gap_m, lead_mps
        to_line, line = best
        state = self.signals.state(line.signal_id, t_s)
        stop = False
        if self.signals.config.mode in ("flashing_red", "dark"):
            if self._signal_cleared != line.signal_id:
                stop = True
                if to_line < 1.5 and self.speed_mps < 0.2:
                    if self._signal_stood_since_s is None:
                        self._signal_stood_since_s = t_s
                    if t_s - self._signal_stood_since_s >= 1.0:
                        self._signal_cleared, stop = line.signal_id, False
        elif state is LightState.RED:
            stop = self._signal_choice != (line.signal_id, "go")  # entered on yellow: committed
        elif state is LightState.YELLOW:
            if self._signal_choice is None or self._signal_choice[0] != line.signal_id:
                can = self.speed_mps**2 / (2.0 * max(to_line, 0.1)) <= self.comfort_decel_mps2
                self._signal_choice = (line.signal_id, "stop" if can else "go")
            stop = self._signal_choice[1] == "stop"
        else:
            self._signal_choice = None
        line_gap = to_line + self.min_gap_m - 0.3
        if stop and line_gap < gap_m:
            return line_gap, 0.0
        return gap_m, lead_mps

    def step(self, world: World, dt_s: float) -> None:
        gap_m, lead_speed_mps = world.leader_on_path(self, horizon_m=50.0)
        # Treat the next uncleared stop line as a standing leader until the arbiter lets us go.
        for to_line, line in self._lines_ahead():
            if line.stop_line_id in self.cleared:
                continue
            if to_line < -1.0:
                self.cleared.add(line.stop_line_id)
                continue
            if to_line < 60.0:
                if to_line < 1.5 and self.speed_mps < 0.2:
                    arbiter = world.arbiter(line.stop_line_id)
                    if self.waiting_at is None:
                        self.waiting_at = line.stop_line_id
                        arbiter.arrive(self.id, line.stop_line_id, world.t_s)
                    if arbiter.may_go(self.id, world.t_s):
                        arbiter.enter(self.id)
                        self.cleared.add(line.stop_line_id)
                        self.waiting_at = None
                        continue
                line_gap = to_line + self.min_gap_m - 0.3
                if line_gap < gap_m:
                    gap_m, lead_speed_mps = line_gap, 0.0
            break
        gap_m, lead_speed_mps = self._signal_gap(world.t_s, gap_m, lead_speed_mps)
        accel = idm_accel_mps2(
            self.speed_mps,
            self.desired_speed_mps * world.path_speed_factor(self),
            gap_m,
            lead_speed_mps,
            self.max_accel_mps2,
            self.comfort_decel_mps2,
            self.min_gap_m,
            self.time_headway_s,
        )
        accel = max(accel, -6.0)
        self.speed_mps = max(0.0, self.speed_mps + accel * dt_s)
        self.s_m += self.speed_mps * dt_s
        if self.s_m >= self.path.length_m and not self.path.closed:
            if self.despawn_at_end:
                self.active = False
            self.s_m = self.path.length_m
            self.speed_mps = 0.0
        x, y, yaw = self.path.point_at(self.s_m)
        self.x_m, self.y_m, self.yaw_rad = x, y, yaw

    def _lines_ahead(self) -> list[tuple[float, StopLineOnPath]]:
        """(distance from the front bumper to the line, line) in the order the car meets them."""
        out = [(line.s_m - self.s_m - self.length_m / 2.0, line) for line in self.stop_lines]
        if not self.path.closed:
            return out
        # On a loop s_m keeps growing past the length: each lap meets every line again, so a line
        # far ahead (more than the look-ahead) is uncleared for the coming lap.
        length_m = self.path.length_m
        wrapped = []
        for to_line, line in out:
            to_line = (to_line + 1.0) % length_m - 1.0
            if to_line > 60.0:
                self.cleared.discard(line.stop_line_id)
            wrapped.append((to_line, line))
        return sorted(wrapped, key=lambda item: item[0])


def idm_accel_mps2(
    v_mps: float,
    v0_mps: float,
    gap_m: float,
    lead_v_mps: float,
    a_max: float,
    b_comf: float,
    s0_m: float,
    headway_s: float,
) -> float:
    """Intelligent driver model (Treiber et al. 2000) acceleration."""
    free = 1.0 - (v_mps / max(v0_mps, 0.1)) ** 4
    if gap_m == math.inf:
        return a_max * free
    dv = v_mps - lead_v_mps
    s_star = s0_m + max(0.0, v_mps * headway_s + v_mps * dv / (2.0 * math.sqrt(a_max * b_comf)))
    return a_max * (free - (s_star / max(gap_m, 0.1)) ** 2)


@dataclass(slots=True, kw_only=True)
class WalkingAgent(Agent):
    """Walks a straight line from ``start`` to ``end`` once it decides to go.

    ``gap_s`` is the time gap to the nearest approaching vehicle it accepts before stepping out; a
    walker on the road keeps walking (pedestrians and geese do not turn back mid-crossing).
    ``trigger_distance_m`` holds the walker until the shuttle is that close (scripted encounters).
    """

    start_xy: tuple[float, float]
    end_xy: tuple[float, float]
    walk_speed_mps: float
    gap_s: float = 4.0
    trigger_distance_m: float = math.inf
    min_trigger_distance_m: float = 0.0
    start_after_s: float = 0.0
    pause_every_m: float = 0.0
    pause_s: float = 0.0
    progress_m: float = 0.0
    walking: bool = False
    done: bool = False
    pause_left_s: float = 0.0
    next_pause_m: float = 0.0
    respawn: bool = False
    mean_gap_s: float = 30.0  # between respawned pedestrians (Poisson arrivals)
    idle_until_s: float = 0.0
    approach_m: float = 0.0  # a respawned pedestrian walks this far up to the kerb, in view
    approach_left_m: float = 0.0

    @property
    def steps_while_away(self) -> bool:
        return self.respawn

    def step(self, world: World, dt_s: float) -> None:
        total = math.dist(self.start_xy, self.end_xy)
        if self.done:
            if self.respawn and world.t_s >= self.idle_until_s:
                # A new pedestrian walks up to a kerb along the sidewalk (visible to sensors on the
                # way, as real ones are, rather than appearing at the kerb); the last one walked off.
                self.done = False
                self.active = True
                self.progress_m = 0.0
                self.approach_left_m = self.approach_m
                self._place_before_kerb(total)
            else:
                return
        if self.approach_left_m > 0.0:
            self.speed_mps = self.walk_speed_mps
            self.approach_left_m = max(0.0, self.approach_left_m - self.walk_speed_mps * dt_s)
            self._place_before_kerb(total)
            return
        if not self.walking:
            self.speed_mps = 0.0
            if world.t_s < self.start_after_s:
                return
            ego_d = world.distance_to_ego_m(self.x_m, self.y_m)
            if not (self.min_trigger_distance_m <= ego_d <= self.trigger_distance_m):
                return
            if world.time_gap_s(self.x_m, self.y_m) < self.gap_s:
                return
            self.walking = True
            self.next_pause_m = self.pause_every_m
        if self.pause_left_s > 0.0:
            self.pause_left_s -= dt_s
            self.speed_mps = 0.0
            return
        self.speed_mps = self.walk_speed_mps
        self.progress_m += self.walk_speed_mps * dt_s
        if self.pause_every_m > 0.0 and self.progress_m >= self.next_pause_m:
            self.pause_left_s = self.pause_s
            self.next_pause_m += self.pause_every_m
        frac = min(self.progress_m / total, 1.0)
        self.x_m = self.start_xy[0] + frac * (self.end_xy[0] - self.start_xy[0])
        self.y_m = self.start_xy[1] + frac * (self.end_xy[1] - self.start_xy[1])
        self.yaw_rad = math.atan2(self.end_xy[1] - self.start_xy[1], self.end_xy[0] - self.start_xy[0])
        if frac >= 1.0:
            self.walking = False
            self.speed_mps = 0.0
            self.done = True
            self.active = False  # off the road and away: it no longer stands at the kerb
            if self.respawn:
                # Next pedestrian arrives at the other kerb after an exponential gap (Poisson arrivals).
                self.start_xy, self.end_xy = self.end_xy, self.start_xy
                self.idle_until_s = world.t_s + float(world.agent_rng.exponential(self.mean_gap_s))

    def _place_before_kerb(self, total_m: float) -> None:
        ux = (self.end_xy[0] - self.start_xy[0]) / total_m
        uy = (self.end_xy[1] - self.start_xy[1]) / total_m
        self.x_m = self.start_xy[0] - self.approach_left_m * ux
        self.y_m = self.start_xy[1] - self.approach_left_m * uy
        self.yaw_rad = math.atan2(uy, ux)


def agent_arrays(agents: list[Agent]) -> np.ndarray:
    """(N, 9) float64 rows: x, y, yaw, vx, vy, length, width, class_id, rcs_dbsm for active agents."""
    rows = [
        (a.x_m, a.y_m, a.yaw_rad, a.vx_mps, a.vy_mps, a.length_m, a.width_m, float(a.cls), a.rcs_dbsm)
        for a in agents
        if a.active
    ]
    return np.array(rows, dtype=np.float64).reshape(-1, 9)
