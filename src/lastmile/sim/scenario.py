"""Scenario files: a TOML table per kind of road user, loaded into frozen, checked dataclasses."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import tomli_w

from lastmile.core.config import check_range, from_mapping, load_toml
from lastmile.core.errors import ConfigError
from lastmile.core.vehicle_messages import BehaviourState
from lastmile.sim.faults import FaultSpec
from lastmile.sim.gnss_scenario import GnssScenario
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.traffic_signals import SignalConfig
from lastmile.sim.weather import parse_weather

MIN_ROAD_USER_SPEED_MPS = 0.05
"""Slowest a moving road user may be (a goose wanders at 0.2-0.5 m/s); zero or less is a typo."""
MAX_CAR_SPEED_MPS = 30.0
"""108 km/h: far above any campus limit, so only nonsense is refused."""
MAX_WALKER_SPEED_MPS = 4.0
"""A running pedestrian; the crosswalk pedestrians share the bound."""


@dataclass(frozen=True, slots=True, kw_only=True)
class RingCar:
    """A car driving the ring: ``direction`` "ccw" shares the shuttle's lane, "cw" is oncoming."""

    direction: Literal["ccw", "cw"] = "cw"
    start_s_m: float = 0.0
    speed_mps: float = 6.0

    def __post_init__(self) -> None:
        check_range("ring_cars.start_s_m", self.start_s_m, 0.0, 1e5)
        check_range("ring_cars.speed_mps", self.speed_mps, MIN_ROAD_USER_SPEED_MPS, MAX_CAR_SPEED_MPS)


@dataclass(frozen=True, slots=True, kw_only=True)
class SideRoadCar:
    """A car (or cyclist) entering from the side road at ``spawn_t_s``, stopping at the all-way stop,
    then turning; turning right merges into the shuttle's lane."""

    spawn_t_s: float = 0.0
    turn: Literal["left", "right"] = "left"
    speed_mps: float = 6.0
    start_m: float = 100.0
    kind: Literal["car", "cyclist"] = "car"

    def __post_init__(self) -> None:
        check_range("side_road_cars.spawn_t_s", self.spawn_t_s, 0.0, 24 * 3600.0)
        check_range("side_road_cars.speed_mps", self.speed_mps, MIN_ROAD_USER_SPEED_MPS, MAX_CAR_SPEED_MPS)
        check_range("side_road_cars.start_m", self.start_m, 0.0, 1e4)


@dataclass(frozen=True, slots=True, kw_only=True)
class MapCar:
    """A car on the map's own lanelet graph (any map): from ``from_lanelet`` (0: drawn from the map's
    road lanelets) along random successors for ``distance_m``, appearing at ``spawn_t_s`` and leaving at
    its path's end; ``every_s`` > 0 makes it a stream, a new car on a new walk that often. It follows
    what is ahead, stops at all-way stops and obeys the signals (see ``sim/map_traffic.py``)."""

    spawn_t_s: float = 0.0
    speed_mps: float = 6.0
    from_lanelet: int = 0
    distance_m: float = 300.0
    every_s: float = 0.0

    def __post_init__(self) -> None:
        check_range("map_cars.spawn_t_s", self.spawn_t_s, 0.0, 24 * 3600.0)
        check_range("map_cars.speed_mps", self.speed_mps, MIN_ROAD_USER_SPEED_MPS, MAX_CAR_SPEED_MPS)
        check_range("map_cars.distance_m", self.distance_m, 1.0, 1e5)
        if self.every_s != 0.0:
            check_range("map_cars.every_s", self.every_s, 1.0, 24 * 3600.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class ParkedCar:
    """A car parked in a stop's bay at its downstream end, partly blocking the stop."""

    stop: str = "S1"
    from_end_m: float = 1.0

    def __post_init__(self) -> None:
        check_range("parked_cars.from_end_m", self.from_end_m, 0.0, 100.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class StaticObstacle:
    """Something standing on or beside the road at the shuttle's route s, ``d_m`` left of its lane centre.

    ``kind`` "object" is a box, barrel or fallen load (class unknown to the stack); "car" is a vehicle
    stopped or parked there (it may hide a pedestrian stepping out from behind it).
    """

    route_s_m: float
    d_m: float = 0.0
    kind: Literal["object", "car"] = "object"
    length_m: float = 0.8
    width_m: float = 0.8

    def __post_init__(self) -> None:
        check_range("static_obstacles.d_m", self.d_m, -8.0, 8.0)
        check_range("static_obstacles.length_m", self.length_m, 0.1, 20.0)
        check_range("static_obstacles.width_m", self.width_m, 0.1, 5.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class CrosswalkPedestrians:
    """Pedestrians crossing at crosswalk number ``crosswalk`` (0-based), Poisson with ``mean_gap_s``.

    Each one after the first walks ``approach_m`` along the sidewalk up to the kerb before judging the
    gap, so that it is in view before it can step out.
    """

    crosswalk: int = 0
    mean_gap_s: float = 40.0
    first_after_s: float = 5.0
    speed_mps: float = 1.3
    approach_m: float = 4.0

    def __post_init__(self) -> None:
        check_range("crosswalk_pedestrians.mean_gap_s", self.mean_gap_s, 0.1, 3600.0)
        check_range("crosswalk_pedestrians.first_after_s", self.first_after_s, 0.0, 24 * 3600.0)
        check_range("crosswalk_pedestrians.speed_mps", self.speed_mps, 0.1, 4.0)
        check_range("crosswalk_pedestrians.approach_m", self.approach_m, 0.0, 50.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class Walker:
    """A single crossing away from crosswalks: a jaywalker, or a goose (``kind``).

    ``route_s_m`` is where on the shuttle's loop it crosses; it steps out when the shuttle is between
    ``min_trigger_m`` and ``trigger_m`` away and the gap to every vehicle is at least ``gap_s``.
    """

    kind: Literal["pedestrian", "goose"] = "pedestrian"
    route_s_m: float = 0.0
    speed_mps: float = 1.4
    trigger_m: float = 45.0
    min_trigger_m: float = 25.0
    gap_s: float = 3.0
    from_left: bool = True

    def __post_init__(self) -> None:
        check_range("walkers.route_s_m", self.route_s_m, 0.0, 1e5)
        check_range("walkers.speed_mps", self.speed_mps, MIN_ROAD_USER_SPEED_MPS, MAX_WALKER_SPEED_MPS)
        check_range("walkers.min_trigger_m", self.min_trigger_m, 0.0, 1000.0)
        check_range("walkers.trigger_m", self.trigger_m, self.min_trigger_m, 1000.0)
        check_range("walkers.gap_s", self.gap_s, 0.0, 60.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class DropOffRequest:
    """A rider on board from the start who presses the drop-off button by their seat at ``t_s``: they
    want to get off at the next safe place, not at a stop (Snow Lion's unscheduled drop-off). They get
    off at the first door opening after the press, wherever the shuttle stands."""

    t_s: float

    def __post_init__(self) -> None:
        check_range("drop_off_requests.t_s", self.t_s, 0.0, 24 * 3600.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class MapSpec:
    """The map the world is built on (and the shuttle's service route on it).

    Attributes:
        name: "campus", the built-in campus map (``src/lastmile/hdmap/data/campus.osm``) with its loop;
            "route", the map and service of the route file ``route``.
        route: a route file (TOML: a Lanelet2 map, its projection, the stops and the service pattern;
            see ``lastmile.hdmap.route_file``), relative to the working directory.
    """

    name: Literal["campus", "route"] = "campus"
    route: str = ""

    def __post_init__(self) -> None:
        if (self.name == "route") != bool(self.route):
            raise ConfigError(
                f"scenario.map: expected a route file exactly when name = 'route', got name = {self.name!r} "
                f"and route = {self.route!r}"
            )


VEHICLE_SETTINGS = ("lateral_controller", "cruise_speed_mps", "serve_all_stops", "perception")
"""Keys that older scenario files carried and that now belong to the run configuration."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Scenario:
    """The world of a run: map, road users, riders, weather, faults and the operators. With the seed and
    a run configuration (the vehicle software: :mod:`lastmile.runner.run_config`) it repeats bit for bit.
    """

    name: str = "default_service"
    minutes: float = 10.0
    seed: int = 0
    weather: str = "clear"
    map: MapSpec = field(default_factory=MapSpec)
    start_route_s_m: float = 0.0
    passengers: PassengerConfig = field(default_factory=PassengerConfig)
    ring_cars: tuple[RingCar, ...] = ()
    side_road_cars: tuple[SideRoadCar, ...] = ()
    map_cars: tuple[MapCar, ...] = ()
    """Cars on the map's own lanelet graph (any map; the campus's ring and side-road cars are above)."""
    parked_cars: tuple[ParkedCar, ...] = ()
    crosswalk_pedestrians: tuple[CrosswalkPedestrians, ...] = ()
    route_crosswalk_pedestrians: CrosswalkPedestrians | None = None
    """Pedestrians, timed as given, at every mapped crosswalk the service route crosses (any map)."""
    walkers: tuple[Walker, ...] = ()
    static_obstacles: tuple[StaticObstacle, ...] = ()
    drop_off_requests: tuple[DropOffRequest, ...] = ()
    """Riders on board who ask to get off between stops (``[[drop_off_requests]] t_s = 95.0``)."""
    faults: tuple[FaultSpec, ...] = ()
    snow_cover_lane_m: float = 0.0
    """In snow, this much of the lane beside the curb lies under snow at curb height (raw LiDAR only)."""
    estop_in_state: str = ""
    """The operator presses the e-stop the first time the stack reports this behaviour state ("": never)."""
    estop_min_speed_mps: float = 0.0
    """...and the shuttle moves at least this fast (an e-stop at standstill proves little)."""
    estop_release_s: float = 8.0
    """How long after standstill the operator releases the e-stop (and confirms the cause is gone)."""
    traffic_signals: SignalConfig = field(default_factory=SignalConfig)
    """Timing and mode (cycle, flashing red / yellow, dark) of the map's traffic signals."""
    gnss: GnssScenario = field(default_factory=GnssScenario)
    """GNSS fix quality, outages, multipath, heavy snow and wheel slip (none: plain RTK GNSS/INS)."""
    checks: tuple[str, ...] = ()
    """Outcome checks a sweep judges this scenario by (names of ``lastmile.runner.sweep.CHECKS``, checked
    there); empty: the generic ones. Suite cases write theirs here, so an exported suite re-runs as is."""

    def __post_init__(self) -> None:
        check_range("scenario.minutes", self.minutes, 0.01, 24 * 60.0)
        if self.seed < 0:  # NumPy's SeedSequence takes none
            raise ConfigError(f"scenario.seed: expected a non-negative integer, got {self.seed}")
        states = [s.value for s in BehaviourState]
        if self.estop_in_state and self.estop_in_state not in states:
            raise ConfigError(
                f"scenario.estop_in_state: expected one of {', '.join(states)} or empty, "
                f"got {self.estop_in_state!r}"
            )
        check_range("scenario.estop_release_s", self.estop_release_s, 0.0, 3600.0)
        check_range("scenario.estop_min_speed_mps", self.estop_min_speed_mps, 0.0, 20.0 / 3.6)
        parse_weather(self.weather)
        # The snow bank (0.6 m) and the cover together stay under 4 m: a lane is 3.5 m wide.
        check_range("scenario.snow_cover_lane_m", self.snow_cover_lane_m, 0.0, 3.4)


def load_scenario(path: Path) -> Scenario:
    """Read and check a scenario TOML file."""
    data = load_toml(path)
    moved = [key for key in VEHICLE_SETTINGS if key in data]
    if moved:
        raise ConfigError(
            f"{path}: {moved[0]!r} is a vehicle setting: expected it in a run configuration's [stack] "
            "table (--config FILE), got it in the scenario"
        )
    return from_mapping(Scenario, data, str(path))


def scenario_to_toml(scenario: Scenario) -> str:
    """The scenario as a TOML file that :func:`load_scenario` reads back to an equal scenario."""
    return tomli_w.dumps(_without_none(dataclasses.asdict(scenario)))


def _without_none(value: Any) -> Any:
    # TOML has no null: an unset optional is simply absent, which loads back as its default None.
    if isinstance(value, dict):
        return {k: _without_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, list | tuple):
        return [_without_none(v) for v in value]
    return value


def route_service(route: str, seed: int = 0, minutes: float = 10.0, weather: str = "clear") -> Scenario:
    """The service on a route file's map, its world drawn from the map as the campus service's is from
    the campus: a rider waiting at every stop and more arriving, pedestrians at every crosswalk the route
    crosses, and a car every 30 s on the map's own lanelet graph (routed on random successors)."""
    return Scenario(
        name="route_service",
        minutes=minutes,
        seed=seed,
        weather=weather,
        map=MapSpec(name="route", route=route),
        passengers=PassengerConfig(arrivals_per_stop_per_min=0.3, initial_waiting_per_stop=1),
        route_crosswalk_pedestrians=CrosswalkPedestrians(),
        map_cars=(MapCar(spawn_t_s=5.0, every_s=30.0, distance_m=400.0),),
    )


def default_service(seed: int = 0, minutes: float = 10.0, weather: str = "clear") -> Scenario:
    """The default campus service: riders at every stop, traffic, a parked car in S1's bay, pedestrians
    at two crosswalks, a jaywalker and a goose crossing."""
    return Scenario(
        name="default_service",
        minutes=minutes,
        seed=seed,
        weather=weather,
        passengers=PassengerConfig(
            arrivals_per_stop_per_min=0.3, initial_waiting={"S1": 1, "S2": 1, "S3": 1, "S4": 1}
        ),
        ring_cars=(
            RingCar(direction="cw", start_s_m=300.0),
            RingCar(direction="cw", start_s_m=1200.0),
            RingCar(direction="ccw", start_s_m=600.0, speed_mps=5.0),
        ),
        side_road_cars=(SideRoadCar(spawn_t_s=20.0, turn="left"), SideRoadCar(spawn_t_s=200.0, turn="right")),
        parked_cars=(ParkedCar(stop="S1"),),
        crosswalk_pedestrians=(
            CrosswalkPedestrians(crosswalk=0),
            CrosswalkPedestrians(crosswalk=2, first_after_s=60.0),
        ),
        walkers=(
            Walker(kind="pedestrian", route_s_m=1080.0),
            Walker(
                kind="goose", route_s_m=1500.0, speed_mps=0.35, trigger_m=40.0, min_trigger_m=20.0, gap_s=0.0
            ),
        ),
    )
