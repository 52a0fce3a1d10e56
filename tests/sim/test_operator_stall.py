"""The safety driver's stall rule at an all-way stop: a queue explains standing, a deadlock does not."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from lastmile.core.run_events import EventKind
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.service_route import load_route
from lastmile.sim.operator import OperatorConfig, OperatorModel
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState
from lastmile.sim.weather import Weather
from lastmile.sim.world import World

ROOT = Path(__file__).resolve().parents[2]
TOWN = ROOT / "examples" / "routes" / "town_block_loop.toml"


class _Referee:
    """What the operator asks of the judge: nothing about to collide, on the road, events kept."""

    def __init__(self, world: World) -> None:
        self.world = world
        self.off_road = False
        self.events: list[tuple[EventKind, dict[str, object]]] = []

    def time_to_collision(self) -> tuple[float, int]:
        return math.inf, -1

    def emit(self, kind: EventKind, **data: object) -> None:
        self.events.append((kind, data))


def _standing_shuttle(rearrive_every_s: float | None) -> list[float]:
    """Times of takeovers over 300 s while the shuttle stands (door shut) and a car waits at an
    all-way stop: the same car all along (a deadlock), or a new arrival every ``rearrive_every_s``."""
    hdmap = load_route(TOWN).hdmap
    ego = KinematicBicycle(
        VehicleGeometry(), ActuatorDynamics(), VehicleState(x_m=100.0, y_m=60.0, yaw_rad=0.0)
    )
    world = World(hdmap, ego, [], Weather.CLEAR, np.random.default_rng(0))
    line = next(sl.id for sl in hdmap.stop_lines if sl.all_way_stop_id is not None)
    referee = _Referee(world)
    operator = OperatorModel(referee, OperatorConfig())  # type: ignore[arg-type]
    car = 7
    world.arbiter(line).arrive(car, line, 0.0)
    takeovers = []
    for tick in range(3000):
        world.t_s = tick * 0.1
        if rearrive_every_s is not None and tick > 0 and tick % round(rearrive_every_s * 10) == 0:
            world.arbiter(line).enter(car)  # its turn came; the next car arrives
            car += 1
            world.arbiter(line).arrive(car, line, world.t_s)
        n = len(referee.events)
        operator.step(stack_requests_takeover=False, door_open=False)
        takeovers += [world.t_s for kind, data in referee.events[n:] if kind == EventKind.TAKEOVER]
    return takeovers


def test_a_deadlock_at_an_all_way_stop_is_taken_over_a_moving_queue_is_not() -> None:
    stall_s = OperatorConfig().stall_s
    deadlock = _standing_shuttle(None)
    # The car's wait explains the shuttle's for stall_s; then the shuttle stands stall_s unexplained.
    assert deadlock and stall_s < deadlock[0] <= 2 * stall_s + 0.2
    assert _standing_shuttle(20.0) == []
