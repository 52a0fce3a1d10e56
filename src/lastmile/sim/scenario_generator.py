"""WATonoBus's scenario generator: parameters sampled or gridded into scenarios (a TOML file and a seed).

A generated scenario is an ordinary :class:`Scenario`; writing it with ``scenario_to_toml`` makes the
file the full description of the case, so a failure found in a sweep replays with ``lastmile run
--scenario FILE``.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import numpy as np

from lastmile.core.config import check_range
from lastmile.core.errors import ConfigError
from lastmile.core.rng import component_rng
from lastmile.hdmap.service_route import load_route
from lastmile.sim.faults import FAULT_MENU, FaultKind, FaultSpec
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.route_stretches import free_stretches
from lastmile.sim.scenario import (
    CrosswalkPedestrians,
    MapSpec,
    RingCar,
    Scenario,
    SideRoadCar,
    StaticObstacle,
    Walker,
)
from lastmile.sim.suites import WEATHERS

# Stretches of the loop (route s, m) where a walker or an obstacle may be placed: away from the stops'
# bays and the all-way stop, so that each sampled encounter is one hazard at a time.
FREE_STRETCHES_M = ((160.0, 300.0), (620.0, 760.0), (1100.0, 1300.0), (1560.0, 1760.0))


@dataclass(frozen=True, slots=True, kw_only=True)
class ScenarioSpace:
    """Ranges the generator samples from (counts inclusive; speeds in m/s; times in s).

    Attributes:
        minutes: length of each generated scenario.
        pedestrians, cyclists, cars, geese: how many of each (min, max).
        pedestrian_speed_mps, goose_speed_mps, car_speed_mps, cyclist_speed_mps: speed ranges.
        crossing_gap_s: the time gap a crossing pedestrian accepts before stepping out.
        trigger_m: how far ahead of the shuttle a walker starts across (min, max).
        weathers: weathers to draw from.
        fault_probability: chance that a scenario carries one fault from ``FAULT_MENU``.
        fault_start_s, fault_duration_s: when the fault starts and how long it lasts.
        static_obstacle_probability: chance of one stationary obstacle in the lane.
        route: a route file (TOML): the scenarios run on its map and service, with their encounters on
            its own free stretches (``route_stretches.free_stretches``); "" for the campus.
    """

    minutes: float = 1.5
    pedestrians: tuple[int, int] = (0, 2)
    cyclists: tuple[int, int] = (0, 1)
    cars: tuple[int, int] = (0, 3)
    geese: tuple[int, int] = (0, 1)
    pedestrian_speed_mps: tuple[float, float] = (0.8, 1.8)
    goose_speed_mps: tuple[float, float] = (0.2, 0.5)
    car_speed_mps: tuple[float, float] = (4.0, 8.0)
    cyclist_speed_mps: tuple[float, float] = (3.0, 6.0)
    crossing_gap_s: tuple[float, float] = (0.0, 4.0)
    trigger_m: tuple[float, float] = (20.0, 45.0)
    weathers: tuple[str, ...] = WEATHERS
    fault_probability: float = 0.5
    fault_start_s: tuple[float, float] = (10.0, 40.0)
    fault_duration_s: tuple[float, float] = (5.0, 30.0)
    static_obstacle_probability: float = 0.2
    route: str = ""

    def __post_init__(self) -> None:
        check_range("space.minutes", self.minutes, 0.1, 60.0)
        check_range("space.fault_probability", self.fault_probability, 0.0, 1.0)
        check_range("space.static_obstacle_probability", self.static_obstacle_probability, 0.0, 1.0)
        for name in ("pedestrians", "cyclists", "cars", "geese"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi <= 20:
                raise ConfigError(f"space.{name}: expected 0 <= min <= max <= 20, got ({lo}, {hi})")
        if not self.weathers or any(w not in WEATHERS for w in self.weathers):
            raise ConfigError(
                f"space.weathers: expected a non-empty subset of {WEATHERS}, got {self.weathers}"
            )


def sample_scenarios(space: ScenarioSpace, count: int, seed: int) -> list[Scenario]:
    """``count`` scenarios drawn from ``space``; the same seed gives the same list."""
    if count < 0:
        raise ConfigError(f"sample_scenarios: expected a count >= 0, got {count}")
    rng = component_rng(seed, "scenario_generator")
    world = _campus_world() if not space.route else _route_world(space)
    return [_sample_one(space, rng, index, seed, world) for index in range(count)]


@dataclass(frozen=True, slots=True, kw_only=True)
class _World:
    """What the generator may use on a map.

    Attributes:
        map: the scenario's map section.
        stretches: route-s intervals for walkers and obstacles.
        car_start_m: the range of a car's start s along its path.
        oncoming_cars: the map has the opposite lane the campus ring offers (``RingCar`` "cw"); on a
            route file's map every car follows the service path ("ccw"), since its lanes may be one-way.
        cyclists: the campus's side road exists for ``SideRoadCar`` cyclists.
        crosswalks: indices of the map's crosswalks on the service path.
    """

    map: MapSpec
    stretches: tuple[tuple[float, float], ...]
    car_start_m: tuple[float, float]
    oncoming_cars: bool
    cyclists: bool
    crosswalks: tuple[int, ...]


def _campus_world() -> _World:
    return _World(
        map=MapSpec(),
        stretches=FREE_STRETCHES_M,
        car_start_m=(60.0, 1900.0),
        oncoming_cars=True,
        cyclists=True,
        crosswalks=(0,),
    )


def _route_world(space: ScenarioSpace) -> _World:
    service = load_route(space.route)
    on_path = tuple(sorted({rc.crosswalk.id for rc in service.layers(step_m=1.0).crosswalks}))
    ids = [cw.id for cw in service.hdmap.crosswalks]
    return _World(
        map=MapSpec(name="route", route=space.route),
        stretches=free_stretches(service, clearance_m=space.trigger_m[1]),
        car_start_m=(0.0, service.length_m),
        oncoming_cars=False,
        cyclists=False,
        crosswalks=tuple(ids.index(cid) for cid in on_path),
    )


def grid_scenarios(
    base: Scenario, weathers: tuple[str, ...], faults: tuple[tuple[FaultKind, str], ...] = FAULT_MENU
) -> list[Scenario]:
    """Every weather crossed with no fault and each (kind, target) fault, on ``base``."""
    out = []
    for weather, fault in itertools.product(weathers, (None, *faults)):
        spec = (
            ()
            if fault is None
            else (FaultSpec(kind=fault[0], target=fault[1], start_s=20.0, duration_s=20.0),)
        )
        tag = "nofault" if fault is None else f"{fault[0]}_{fault[1]}"
        out.append(
            dataclasses.replace(base, name=f"{base.name}_{weather}_{tag}", weather=weather, faults=spec)
        )
    return out


def _crosswalk_pedestrians(
    rng: np.random.Generator, crosswalks: tuple[int, ...]
) -> tuple[CrosswalkPedestrians, ...]:
    """Half the scenarios get pedestrians at one crosswalk of the path (the campus has one choice, so
    its draws are as before)."""
    if not rng.random() < 0.5 or not crosswalks:
        return ()
    index = crosswalks[int(rng.integers(len(crosswalks)))] if len(crosswalks) > 1 else crosswalks[0]
    return (CrosswalkPedestrians(crosswalk=index, first_after_s=float(rng.uniform(0.0, 30.0))),)


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return round(float(rng.uniform(bounds[0], bounds[1])), 3)


def _count(rng: np.random.Generator, bounds: tuple[int, int]) -> int:
    return int(rng.integers(bounds[0], bounds[1] + 1))


def _where(rng: np.random.Generator, stretches: tuple[tuple[float, float], ...]) -> float:
    lo, hi = stretches[int(rng.integers(len(stretches)))]
    return round(float(rng.uniform(lo, hi)), 1)


def _sample_one(
    space: ScenarioSpace, rng: np.random.Generator, index: int, seed: int, world: _World
) -> Scenario:
    weather = space.weathers[int(rng.integers(len(space.weathers)))]
    walkers = [
        Walker(
            kind="pedestrian",
            route_s_m=_where(rng, world.stretches),
            speed_mps=_uniform(rng, space.pedestrian_speed_mps),
            trigger_m=(trig := _uniform(rng, space.trigger_m)),
            min_trigger_m=round(trig * 0.6, 3),
            gap_s=_uniform(rng, space.crossing_gap_s),
            from_left=bool(rng.integers(2)),
        )
        for _ in range(_count(rng, space.pedestrians))
    ]
    walkers += [
        Walker(
            kind="goose",
            route_s_m=_where(rng, world.stretches),
            speed_mps=_uniform(rng, space.goose_speed_mps),
            trigger_m=(trig := _uniform(rng, space.trigger_m)),
            min_trigger_m=round(trig * 0.5, 3),
            gap_s=0.0,
            from_left=bool(rng.integers(2)),
        )
        for _ in range(_count(rng, space.geese))
    ]
    cars = [
        RingCar(
            direction="cw" if rng.random() < 0.6 and world.oncoming_cars else "ccw",
            start_s_m=round(float(rng.uniform(*world.car_start_m)), 1),
            speed_mps=_uniform(rng, space.car_speed_mps),
        )
        for _ in range(_count(rng, space.cars))
    ]
    cyclists = [
        SideRoadCar(
            spawn_t_s=_uniform(rng, (5.0, 60.0)),
            turn="right" if rng.random() < 0.5 else "left",
            kind="cyclist",
            speed_mps=_uniform(rng, space.cyclist_speed_mps),
        )
        for _ in range(_count(rng, space.cyclists))
    ]
    if not world.cyclists:  # drawn all the same, so each scenario's other draws do not shift
        cyclists = []
    obstacles = (
        (StaticObstacle(route_s_m=_where(rng, world.stretches), d_m=_uniform(rng, (-0.5, 0.5))),)
        if rng.random() < space.static_obstacle_probability
        else ()
    )
    faults: tuple[FaultSpec, ...] = ()
    if rng.random() < space.fault_probability:
        kind, target = FAULT_MENU[int(rng.integers(len(FAULT_MENU)))]
        faults = (
            FaultSpec(
                kind=kind,
                target=target,
                start_s=_uniform(rng, space.fault_start_s),
                duration_s=_uniform(rng, space.fault_duration_s),
            ),
        )
    return Scenario(
        name=f"generated_{seed}_{index:05d}",
        map=world.map,
        minutes=space.minutes,
        seed=seed * 100_003 + index,
        weather=weather,
        passengers=PassengerConfig(arrivals_per_stop_per_min=0.0),
        ring_cars=tuple(cars),
        side_road_cars=tuple(cyclists),
        walkers=tuple(walkers),
        static_obstacles=obstacles,
        crosswalk_pedestrians=_crosswalk_pedestrians(rng, world.crosswalks),
        faults=faults,
    )
