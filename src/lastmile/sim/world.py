"""The simulated world: ground truth of the shuttle, the agents, the all-way stop and the weather.

Only the simulator, the judge and the operator model read this. The stack sees the world through
:mod:`lastmile.sim.sensors` alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.geometry import PreparedPolygon, rectangle_corners_m
from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.model import HDMap, StopLine
from lastmile.sim.agents import Agent, PathCar
from lastmile.sim.arbiter import EGO_ID, AllWayStopArbiter
from lastmile.sim.vehicle_model import KinematicBicycle
from lastmile.sim.weather import WEATHER_EFFECTS, Weather, WeatherEffects


@dataclass(frozen=True, slots=True)
class StopLineTruth:
    """A stop line reduced to what the simulator needs: its midpoint and the entry direction."""

    id: int
    mid_x_m: float
    mid_y_m: float
    heading_rad: float
    all_way_stop_id: int | None
    stop_sign_id: int | None = None


class World:
    """Everything that exists, advanced one base tick at a time by the runner."""

    def __init__(
        self,
        hdmap: HDMap,
        ego: KinematicBicycle,
        agents: list[Agent],
        weather: Weather,
        agent_rng: np.random.Generator,
    ) -> None:
        self.hdmap = hdmap
        self.ego = ego
        self.geometry: VehicleGeometry = ego.geometry
        self.agents = agents
        self.weather = weather
        self.effects: WeatherEffects = WEATHER_EFFECTS[weather]
        self.agent_rng = agent_rng
        self.t_s = 0.0
        # One arbiter per all-way stop: arrival order and an occupied box are an intersection's own; a
        # car waiting at one junction owes nothing to a car at another.
        self.arbiters = {aws.id: AllWayStopArbiter() for aws in hdmap.all_way_stops}
        self._arbiter_of_line = {
            sl.id: self.arbiters[sl.all_way_stop_id]
            for sl in hdmap.stop_lines
            if sl.all_way_stop_id is not None and sl.all_way_stop_id in self.arbiters
        }
        self.stop_lines = [_stop_line_truth(hdmap, sl) for sl in hdmap.stop_lines]
        self.boxes = {aws.id: PreparedPolygon(aws.conflict_polygon) for aws in hdmap.all_way_stops}
        self._leader_cache: dict[int, tuple[float, float, float]] = {}
        self._vehicles_cache_t = -1.0
        self._vehicles: list[tuple[int, float, float, float, float, float, float]] = []

    # --- the shuttle's ground truth -----------------------------------------------------------
    def ego_centre(self) -> tuple[float, float]:
        s, g = self.ego.state, self.geometry
        off = g.length_m / 2.0 - g.rear_overhang_m
        return s.x_m + off * math.cos(s.yaw_rad), s.y_m + off * math.sin(s.yaw_rad)

    def ego_front(self) -> tuple[float, float]:
        s, g = self.ego.state, self.geometry
        off = g.front_from_rear_axle_m
        return s.x_m + off * math.cos(s.yaw_rad), s.y_m + off * math.sin(s.yaw_rad)

    def ego_corners(self) -> np.ndarray:
        s, g = self.ego.state, self.geometry
        return rectangle_corners_m(s.x_m, s.y_m, s.yaw_rad, g.length_m, g.width_m, g.rear_overhang_m)

    def distance_to_ego_m(self, x_m: float, y_m: float) -> float:
        cx, cy = self.ego_centre()
        return math.hypot(x_m - cx, y_m - cy)

    # --- what agents ask of the world -------------------------------------------------------------
    def vehicles(self) -> list[tuple[int, float, float, float, float, float, float]]:
        """(id, x, y, yaw, speed, length, width) of the shuttle and every active car, cached per tick."""
        if self._vehicles_cache_t != self.t_s:
            cx, cy = self.ego_centre()
            s, g = self.ego.state, self.geometry
            rows = [(EGO_ID, cx, cy, s.yaw_rad, s.speed_mps, g.length_m, g.width_m)]
            rows += [
                (a.id, a.x_m, a.y_m, a.yaw_rad, a.speed_mps, a.length_m, a.width_m)
                for a in self.agents
                if a.active and a.cls == ObjectClass.CAR
            ]
            self._vehicles = rows
            self._vehicles_cache_t = self.t_s
        return self._vehicles

    def leader_on_path(self, car: PathCar, horizon_m: float) -> tuple[float, float]:
        """Bumper-to-bumper gap and speed of the nearest thing ahead on ``car``'s path.

        Recomputed every 0.1 s (and extrapolated in between) because projecting every road user on
        every car's path at 100 Hz would dominate the simulator's cost for no visible difference.
        """
        cached = self._leader_cache.get(car.id)
        if cached is not None and self.t_s - cached[0] < 0.099:
            return cached[1] - car.speed_mps * (self.t_s - cached[0]) + cached[2] * (
                self.t_s - cached[0]
            ), cached[2]
        best_gap, best_v = math.inf, 0.0
        candidates: list[tuple[float, float, float, float, float, float]] = []
        for vid, x, y, yaw, v, length, width in self.vehicles():
            if vid != car.id:
                candidates.append((x, y, yaw, v, length, width))
        for a in self.agents:
            if a.active and a.cls != ObjectClass.CAR and a.speed_mps >= 0.0:
                candidates.append((a.x_m, a.y_m, a.yaw_rad, a.speed_mps, a.length_m, a.width_m))
        for x, y, yaw, v, length, width in candidates:
            dist = math.hypot(x - car.x_m, y - car.y_m)
            if dist > horizon_m:
                continue
            f = car.path.project(x, y, hint_s_m=car.s_m + dist, window_m=dist + 5.0)
            ds = f.s_m - car.s_m
            if car.path.closed:
                # project() answers on [0, L) while a looping car's s_m keeps growing past L: compare
                # on the circle, or a car that has lapped once no longer sees anything ahead of it.
                half_m = car.path.length_m / 2.0
                ds = (ds + half_m) % car.path.length_m - half_m
            if ds <= 0.0 or abs(f.d_m) > car.width_m / 2.0 + width / 2.0 + 0.3:
                continue
            gap = ds - car.length_m / 2.0 - length / 2.0
            if gap < best_gap:
                heading = car.path.heading_at(f.s_m)
                best_gap, best_v = gap, max(0.0, v * math.cos(yaw - heading))
        self._leader_cache[car.id] = (self.t_s, best_gap, best_v)
        return best_gap, best_v

    def path_speed_factor(self, car: PathCar) -> float:
        """Cars slow in curves so lateral acceleration stays under 1.5 m/s^2."""
        kappa = abs(car.path.curvature_at(car.s_m + 8.0, window_m=4.0))
        if kappa < 1e-4:
            return 1.0
        return min(1.0, math.sqrt(1.5 / kappa) / max(car.desired_speed_mps, 0.1))

    def time_gap_s(self, x_m: float, y_m: float) -> float:
        """Time until the nearest approaching vehicle reaches a point (as a pedestrian judges a gap)."""
        gap = math.inf
        for _vid, vx, vy, yaw, v, length, _width in self.vehicles():
            dx, dy = x_m - vx, y_m - vy
            dist = math.hypot(dx, dy)
            along = dx * math.cos(yaw) + dy * math.sin(yaw)
            lateral = abs(-dx * math.sin(yaw) + dy * math.cos(yaw))
            if along < -length / 2.0 or lateral > 8.0 or dist > 80.0:
                continue
            if v < 0.3:
                # A stopped vehicle close by still blocks the pedestrian's view and path.
                if along < length / 2.0 + 1.5:
                    gap = 0.0
                continue
            gap = min(gap, max(0.0, along - length / 2.0) / v)
        return gap

    # --- all-way stop -------------------------------------------------------------------------
    def arbiter(self, stop_line_id: int) -> AllWayStopArbiter:
        """The arbiter of the all-way stop whose stop line ``stop_line_id`` is."""
        return self._arbiter_of_line[stop_line_id]

    def anyone_waiting_at_all_way_stops(self, arrived_after_s: float = -math.inf) -> bool:
        """Whether a vehicle waits at any all-way stop, counting only those that arrived after
        ``arrived_after_s`` (a turn that has not come for that long is a deadlock, not a queue)."""
        return any(
            t > arrived_after_s for arbiter in self.arbiters.values() for t, _ in arbiter.queue.values()
        )

    def update_intersections(self) -> None:
        vehicles = self.vehicles()
        for stop_id, box in self.boxes.items():
            self.arbiters[stop_id].box_occupied_by = {vid for vid, x, y, *_ in vehicles if box.contains(x, y)}

    def ego_stop_line_distance(self, line: StopLineTruth) -> float | None:
        """Distance from the shuttle's front bumper to a stop line it is approaching, else None."""
        fx, fy = self.ego_front()
        heading = line.heading_rad
        if math.cos(self.ego.state.yaw_rad - heading) < 0.7:
            return None
        dx, dy = line.mid_x_m - fx, line.mid_y_m - fy
        along = dx * math.cos(heading) + dy * math.sin(heading)
        lateral = -dx * math.sin(heading) + dy * math.cos(heading)
        if abs(lateral) > 2.5 or along < -6.0 or along > 30.0:
            return None
        return along


def _stop_line_truth(hdmap: HDMap, stop_line: StopLine) -> StopLineTruth:
    line = np.asarray(stop_line.line, dtype=np.float64)
    lanelet = hdmap.lanelets[stop_line.lanelet_id]
    centre: Polyline = lanelet.centerline
    heading = centre.heading_at(centre.length_m - 0.1)
    mid = line.mean(axis=0)
    return StopLineTruth(
        id=stop_line.id,
        mid_x_m=float(mid[0]),
        mid_y_m=float(mid[1]),
        heading_rad=heading,
        all_way_stop_id=stop_line.all_way_stop_id,
        stop_sign_id=stop_line.stop_sign_id,
    )
