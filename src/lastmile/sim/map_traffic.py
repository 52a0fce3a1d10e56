"""Cars that drive the map's own lanelet graph, on any map: the traffic of a route file's world.

Each ``MapCar`` of the scenario starts on a lanelet (given, or drawn from the map's road lanelets) and
drives a random walk over the lanelet graph's successors (``HDMap.successor_ids``: the routing graph's
following lanelets, so one-way rules and turn lanes hold) for its distance, then leaves. On the way it
is an ordinary ``PathCar``: the intelligent driver model behind whatever is ahead (the shuttle
included), a stop at every all-way-stop line with the world's arbiter, and the signals. With
``every_s`` the spec is a stream: another car on a fresh walk every that many seconds.

Every draw comes from the scenario's seed through its own stream per car, so a run repeats bit for bit,
and a car that would appear within ``SPAWN_CLEARANCE_M`` of another road user waits a second.
"""

from __future__ import annotations

import math

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.rng import component_rng
from lastmile.hdmap.model import HDMap
from lastmile.hdmap.routing import route_polyline
from lastmile.sim.agents import CAR_LENGTH_M, CAR_WIDTH_M, PathCar, StopLineOnPath
from lastmile.sim.scenario import MapCar
from lastmile.sim.sensors import RCS_DBSM
from lastmile.sim.world import World

SPAWN_CLEARANCE_M = 12.0
"""A car appears only where nothing is this close: its own length and a 1.5 s headway at town speeds
would not fit in less."""

ROAD_SUBTYPES = frozenset({"road", "highway", "play_street", "bus_lane"})
"""Lanelet2's subtypes a car may start on (not crosswalks, walkways, bicycle lanes or stop bays)."""


class MapTraffic:
    """The scenario's map cars: pending spawns, each built when its time comes."""

    def __init__(self, specs: tuple[MapCar, ...], hdmap: HDMap, seed: int) -> None:
        self.hdmap = hdmap
        self.seed = seed
        self._roads = sorted(lid for lid, ll in hdmap.lanelets.items() if ll.subtype in ROAD_SUBTYPES)
        for spec in specs:
            if spec.from_lanelet and spec.from_lanelet not in hdmap.lanelets:
                raise ConfigError(
                    f"map_cars.from_lanelet: expected a lanelet of map {hdmap.name!r}, "
                    f"got {spec.from_lanelet}"
                )
        if specs and not self._roads:
            raise ConfigError(f"map_cars: expected road lanelets on map {hdmap.name!r}, got none")
        # (due time, spec index, how many of this spec so far)
        self._pending = sorted((spec.spawn_t_s, k, 0) for k, spec in enumerate(specs))
        self._specs = specs

    def spawn_due(self, world: World, next_id: int) -> list[PathCar]:
        """The cars due by ``world.t_s`` that have room to appear, with ids from ``next_id`` on."""
        born: list[PathCar] = []
        while self._pending and self._pending[0][0] <= world.t_s:
            due_s, k, n = self._pending.pop(0)
            spec = self._specs[k]
            car = self._build(spec, k, n, next_id + len(born))
            if not _room_for(car, world):
                self._insert((due_s + 1.0, k, n))  # try again in a second, the same car
                continue
            born.append(car)
            if spec.every_s > 0.0:
                self._insert((due_s + spec.every_s, k, n + 1))
        return born

    def _insert(self, item: tuple[float, int, int]) -> None:
        self._pending.append(item)
        self._pending.sort()

    def _build(self, spec: MapCar, k: int, n: int, agent_id: int) -> PathCar:
        rng = component_rng(self.seed, f"map_car_{k}_{n}")
        start = spec.from_lanelet or self._roads[int(rng.integers(len(self._roads)))]
        walk = random_walk(self.hdmap, start, spec.distance_m, rng)
        path = keep_right(route_polyline(self.hdmap, walk), self.hdmap, walk)
        x, y, yaw = path.point_at(0.0)
        return PathCar(
            id=agent_id,
            cls=ObjectClass.CAR,
            x_m=x,
            y_m=y,
            yaw_rad=yaw,
            speed_mps=spec.speed_mps,
            length_m=CAR_LENGTH_M,
            width_m=CAR_WIDTH_M,
            rcs_dbsm=RCS_DBSM[ObjectClass.CAR],
            path=path,
            s_m=0.0,
            desired_speed_mps=spec.speed_mps,
            stop_lines=all_way_stop_lines_on(path, self.hdmap),
            despawn_at_end=True,
        )


def random_walk(hdmap: HDMap, start: int, distance_m: float, rng: np.random.Generator) -> tuple[int, ...]:
    """Lanelets from ``start`` along uniformly drawn successors until ``distance_m`` is covered or the
    graph ends (a lanelet with no successor: the map's edge)."""
    ids = [start]
    covered = hdmap.lanelets[start].centerline.length_m
    while covered < distance_m:
        nexts = hdmap.successor_ids.get(ids[-1], ())
        if not nexts:
            break
        ids.append(nexts[int(rng.integers(len(nexts)))])
        covered += hdmap.lanelets[ids[-1]].centerline.length_m
    return tuple(ids)


def keep_right(path: Polyline, hdmap: HDMap, walk: tuple[int, ...]) -> Polyline:
    """On a lanelet both directions share (a two-way lanelet: the map holds it and its reverse), a car
    keeps to the right half, its path a quarter of the lanelet's width right of the centre line; on
    one-way lanelets the centre line is its lane. A walk over both kinds takes the narrowest two-way
    lanelet's quarter throughout (a sideways jump where the kind changes would be no driver's path)."""
    shared = [lid for lid in walk if -lid in hdmap.lanelets]
    if not shared:
        return path
    quarter = min(_width_m(hdmap, lid) for lid in shared) / 4.0
    return path.offset(-quarter)


def _width_m(hdmap: HDMap, lanelet_id: int) -> float:
    info = hdmap.lanelets[lanelet_id]
    x, y, _ = info.centerline.point_at(info.centerline.length_m / 2.0)
    return abs(info.left.project(x, y).d_m) + abs(info.right.project(x, y).d_m)


def all_way_stop_lines_on(path: Polyline, hdmap: HDMap) -> list[StopLineOnPath]:
    """The all-way-stop lines a car on ``path`` meets: on the path and facing its direction."""
    out = []
    for sl in hdmap.stop_lines:
        if sl.all_way_stop_id is None:
            continue
        mid = np.asarray(sl.line, dtype=float).mean(axis=0)
        f = path.project(float(mid[0]), float(mid[1]))
        lanelet = hdmap.lanelets[sl.lanelet_id].centerline
        heading = lanelet.heading_at(lanelet.length_m - 0.1)
        if abs(f.d_m) < 2.0 and math.cos(path.heading_at(f.s_m) - heading) > 0.7:
            out.append(StopLineOnPath(s_m=f.s_m, stop_line_id=sl.id))
    return sorted(out, key=lambda line: line.s_m)


def _room_for(car: PathCar, world: World) -> bool:
    for _vid, x, y, *_ in world.vehicles():
        if math.hypot(x - car.x_m, y - car.y_m) < SPAWN_CLEARANCE_M:
            return False
    near = (a for a in world.agents if a.active)
    return all(math.hypot(a.x_m - car.x_m, a.y_m - car.y_m) >= SPAWN_CLEARANCE_M for a in near)
