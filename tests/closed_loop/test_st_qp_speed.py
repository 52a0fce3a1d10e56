"""Snow Lion's s-t + QP speed planner selected (``speed_planner = "st_qp"``), closed loop, campus, radar.

Behind a slower car it settles at the car's speed with the gap and headway kept (the default
longitudinal law, which brakes for decision's stop point behind the car, swings between 2.7 and
3.9 m/s in the same scenario); for a pedestrian crossing slowly ahead it comes to rest before them and
goes on once they are across.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lastmile.planning.speed_planning import SpeedPlannerName
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import RingCar, Scenario, Walker
from tests.closed_loop.harness import RADAR, steps

pytestmark = pytest.mark.closed_loop
NO_RIDERS = PassengerConfig(arrivals_per_stop_per_min=0.0, initial_waiting={})
ST_QP = dataclasses.replace(
    RADAR, stack=dataclasses.replace(RADAR.stack, speed_planner=SpeedPlannerName.ST_QP)
)


def _events(step: object, *kinds: str) -> list[tuple[float, str, dict]]:
    return [e for e in step.sim.judge.events if e[1] in kinds]  # type: ignore[attr-defined]


def test_follows_a_slower_lead_car_at_its_speed() -> None:
    """A car 40 m ahead in the shuttle's lane at 3 m/s; the shuttle starts at rest (cruise 5.6 m/s)."""
    scenario = Scenario(
        name="lead",
        minutes=0.55,
        passengers=NO_RIDERS,
        ring_cars=(RingCar(direction="ccw", start_s_m=40.0, speed_mps=3.0),),
    )
    speeds, accels, gaps = [], [], []
    last = None
    for step in steps(scenario, config=ST_QP):
        last = step
        w = step.sim.world
        car = next(a for a in w.agents if a.cls.name == "CAR")
        ego = w.ego_corners()
        if step.t_s > 25.0:
            speeds.append(w.ego.state.speed_mps)
            accels.append(step.out.command.accel_mps2)
        gaps.append(car.x_m - car.length_m / 2.0 - float(ego[:, 0].max()))
    assert last is not None
    assert not _events(last, "collision", "takeover", "rule_violation"), last.sim.judge.events  # type: ignore[attr-defined]
    # Settled behind it: its speed, smooth, and the 3 m gap plus 1.5 s of headway (7.5 m) kept.
    assert min(speeds) > 2.7 and max(speeds) < 3.4, (min(speeds), max(speeds))
    assert max(np.abs(accels)) < 0.3, max(np.abs(accels))
    assert min(gaps) > 6.0, min(gaps)


def test_comes_to_rest_for_a_pedestrian_crossing_slowly_and_goes_on() -> None:
    """A pedestrian steps out across the lane at route s 220 at 0.6 m/s when the shuttle is 30-40 m away."""
    walker = Walker(
        kind="pedestrian", route_s_m=220.0, speed_mps=0.6, trigger_m=40.0, min_trigger_m=30.0, gap_s=0.0
    )
    scenario = Scenario(
        name="crossing", minutes=0.75, passengers=NO_RIDERS, start_route_s_m=150.0, walkers=(walker,)
    )
    rested_before = False
    closest_m = np.inf
    last = None
    for step in steps(scenario, config=ST_QP):
        last = step
        w = step.sim.world
        ped = next(a for a in w.agents if a.cls.name == "PEDESTRIAN")
        ego = w.ego_corners()
        in_lane = ped.active and -3.5 < ped.y_m < 0.0 and ped.x_m > float(ego[:, 0].max())
        if in_lane:
            closest_m = min(closest_m, ped.x_m - float(ego[:, 0].max()))
            rested_before |= w.ego.state.speed_mps < 0.05
    assert last is not None
    assert rested_before, "it never came to rest while the pedestrian was in its lane ahead"
    assert closest_m > 2.0, closest_m
    assert not _events(last, "collision", "takeover"), last.sim.judge.events  # type: ignore[attr-defined]
    assert last.sim.judge.route_s_m > 240.0, "it did not go on"  # type: ignore[attr-defined]
