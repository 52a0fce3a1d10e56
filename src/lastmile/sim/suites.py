"""Named scenario suites: the ISO 22737-style test plan for a low-speed shuttle on its predefined route.

ISO 22737 (low-speed automated driving systems on predefined routes) frames the plan: hazard
determination with a non-occluded and an occluded view, staying in the drivable area, a minimal risk
manoeuvre on every fault, and an emergency stop from every state. Each case is a scenario (a TOML file
and a seed) plus the checks its outcome must pass; the sweep runner evaluates them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from lastmile.core.errors import ConfigError
from lastmile.core.vehicle_messages import BehaviourState
from lastmile.sim.faults import FAULT_MENU, FaultSpec
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import (
    Scenario,
    SideRoadCar,
    StaticObstacle,
    Walker,
    default_service,
)

WEATHERS = ("clear", "rain", "snow", "fog")
SHUTTLE_SPEEDS_MPS = (20.0 / 3.6, 12.0 / 3.6)
"""The speeds the shuttle uses: its 20 km/h top speed and the 12 km/h of shared paths."""

# Where on the loop the encounters happen: the straight between crosswalk C1 (route s 130) and the
# all-way stop (s 330), far from stops and junctions.
ENCOUNTER_S_M = 260.0
CAR_TURNING_IN_SPAWN_S = {"20kph": 56.0, "12kph": 68.0}
"""When the side-road car of ``car_turning_in`` appears, per shuttle speed."""

GENERIC_CHECKS = ("no_stack_crash", "no_collision_at_fault", "no_takeover", "in_drivable_area")
FAULT_CHECKS = ("no_stack_crash", "no_collision_at_fault", "in_drivable_area", "fault_answered")
"""With a fault injected, a takeover request can be the right answer (GNSS lost): it is not a failure."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SuiteCase:
    """One scenario of a suite and what its outcome must show.

    Attributes:
        name: unique, readable (it names the scenario file).
        scenario: the scenario (with its seed).
        checks: names of outcome checks (see ``runner.sweep.CHECKS``).
        group: the test-plan heading it belongs to.
        cruise_speed_mps: the shuttle speed the case is run at (set in the case's run configuration;
            None: the configuration's own).
    """

    name: str
    scenario: Scenario
    checks: tuple[str, ...]
    group: str
    cruise_speed_mps: float | None = None


def _encounter_base(name: str, weather: str, seed: int, minutes: float = 1.4) -> Scenario:
    # No riders and no stops to serve: the shuttle drives the loop from s = 0 through the encounter.
    return Scenario(
        name=name,
        minutes=minutes,
        seed=seed,
        weather=weather,
        passengers=PassengerConfig(arrivals_per_stop_per_min=0.0),
    )


def _speed_tag(speed_mps: float) -> str:
    return f"{round(speed_mps * 3.6):d}kph"


def iso22737_suite(seed: int = 0) -> list[SuiteCase]:
    """The whole plan: hazards in four weathers at both speeds, faults, e-stops, drivable area."""
    cases: list[SuiteCase] = []
    for weather in WEATHERS:
        for speed in SHUTTLE_SPEEDS_MPS:
            tag = f"{weather}_{_speed_tag(speed)}"
            base = _encounter_base("", weather, seed)
            cases.append(
                SuiteCase(
                    name=f"stationary_obstacle_in_lane_{tag}",
                    scenario=dataclasses.replace(
                        base,
                        name=f"stationary_obstacle_in_lane_{tag}",
                        static_obstacles=(StaticObstacle(route_s_m=ENCOUNTER_S_M, d_m=0.0),),
                    ),
                    checks=(*GENERIC_CHECKS, "no_collision"),
                    group="hazard, clear view",
                    cruise_speed_mps=speed,
                )
            )
            cases.append(
                SuiteCase(
                    name=f"pedestrian_crossing_clear_view_{tag}",
                    scenario=dataclasses.replace(
                        base,
                        name=f"pedestrian_crossing_clear_view_{tag}",
                        walkers=(
                            Walker(
                                kind="pedestrian",
                                route_s_m=ENCOUNTER_S_M,
                                from_left=True,
                                trigger_m=40.0,
                                min_trigger_m=25.0,
                                gap_s=0.0,
                            ),
                        ),
                    ),
                    checks=(*GENERIC_CHECKS, "no_collision"),
                    group="hazard, clear view",
                    cruise_speed_mps=speed,
                )
            )
            cases.append(
                SuiteCase(
                    name=f"pedestrian_behind_parked_vehicle_{tag}",
                    scenario=dataclasses.replace(
                        base,
                        name=f"pedestrian_behind_parked_vehicle_{tag}",
                        # A van parked on the right verge; the pedestrian steps out just past its front.
                        static_obstacles=(
                            StaticObstacle(
                                route_s_m=ENCOUNTER_S_M - 3.5, d_m=-3.4, kind="car", length_m=5.0, width_m=2.0
                            ),
                        ),
                        walkers=(
                            Walker(
                                kind="pedestrian",
                                route_s_m=ENCOUNTER_S_M,
                                from_left=False,
                                speed_mps=1.4,
                                trigger_m=24.0,
                                min_trigger_m=16.0,
                                gap_s=0.0,
                            ),
                        ),
                    ),
                    checks=(*GENERIC_CHECKS, "no_collision"),
                    group="hazard, occluded view",
                    cruise_speed_mps=speed,
                )
            )
            cases.append(
                _side_road_case(
                    base,
                    f"cyclist_merging_{tag}",
                    SideRoadCar(spawn_t_s=40.0, turn="right", kind="cyclist", speed_mps=4.5, start_m=60.0),
                    speed,
                )
            )
            # A car turning right from the side road into the shuttle's lane just ahead of it. The
            # spawn times put the turn in front of the shuttle at each speed (found by sweeping them:
            # without decision's cut-in rule the shuttle hit the car at 20 km/h in all four weathers).
            spawn_s = CAR_TURNING_IN_SPAWN_S[_speed_tag(speed)]
            cases.append(
                _side_road_case(
                    base,
                    f"car_turning_in_{tag}",
                    SideRoadCar(spawn_t_s=spawn_s, turn="right", kind="car", speed_mps=6.0, start_m=60.0),
                    speed,
                )
            )
    for fault in _suite_faults():
        name = f"fault_{fault.kind}_{fault.target}"
        cases.append(
            SuiteCase(
                name=name,
                scenario=dataclasses.replace(
                    _encounter_base(name, "clear", seed, minutes=1.5), faults=(fault,)
                ),
                checks=FAULT_CHECKS,
                group="minimal risk manoeuvre on faults",
                cruise_speed_mps=SHUTTLE_SPEEDS_MPS[0],
            )
        )
    cases.extend(_estop_cases(seed))
    for weather in WEATHERS:
        name = f"drivable_area_service_{weather}"
        cases.append(
            SuiteCase(
                name=name,
                scenario=dataclasses.replace(
                    default_service(seed=seed, minutes=4.0, weather=weather), name=name
                ),
                checks=(*GENERIC_CHECKS, "no_rule_violation"),
                group="staying in the drivable area",
            )
        )
    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        raise ConfigError("iso22737_suite: expected unique case names, got duplicates")
    return cases


# Press while the shuttle moves where the state has motion: at cruise in normal driving, rolling on the
# approach, the swing to the curb and the pull-out. Onboarding happens at standstill (doors open).
ESTOP_MIN_SPEED_MPS = {
    BehaviourState.NORMAL_DRIVING: 4.0,
    BehaviourState.INTERSECTION: 1.0,
    BehaviourState.PULLOVER: 1.0,
    BehaviourState.MERGING: 1.0,
}


def _side_road_case(base: Scenario, name: str, road_user: SideRoadCar, speed_mps: float) -> SuiteCase:
    """A hazard from the side road: ``road_user`` enters the ring at the all-way stop (2 minutes)."""
    return SuiteCase(
        name=name,
        scenario=dataclasses.replace(base, name=name, minutes=2.0, side_road_cars=(road_user,)),
        checks=(*GENERIC_CHECKS, "no_collision", "no_rule_violation"),
        group="hazard, clear view",
        cruise_speed_mps=speed_mps,
    )


def _estop_cases(seed: int) -> list[SuiteCase]:
    """The operator's e-stop pressed in each decision state, on the service where that state occurs.

    EMERGENCY_STOP is reached first through a hung localization module (an E-STOP fault), and the
    operator presses the button on top of it; the release then also needs the fault to be gone.
    """
    cases = []
    for state in BehaviourState:
        name = f"estop_from_{state.value}"
        base = default_service(seed=seed, minutes=4.0)
        faults: tuple[FaultSpec, ...] = ()
        if state == BehaviourState.EMERGENCY_STOP:
            faults = (FaultSpec(kind="module_hang", target="localization", start_s=20.0, duration_s=6.0),)
        cases.append(
            SuiteCase(
                name=name,
                scenario=dataclasses.replace(
                    base,
                    name=name,
                    estop_in_state=state.value,
                    estop_min_speed_mps=ESTOP_MIN_SPEED_MPS.get(state, 0.0),
                    faults=faults,
                ),
                checks=("no_stack_crash", "no_collision_at_fault", "in_drivable_area", "estop_honoured"),
                group="emergency stop from every state",
            )
        )
    return cases


def _suite_faults() -> list[FaultSpec]:
    """One fault of every kind on a representative target, starting 20 s into the drive."""
    return [FaultSpec(kind=kind, target=target, start_s=20.0, duration_s=30.0) for kind, target in FAULT_MENU]


SUITES = {"iso22737": iso22737_suite}
"""Suites by name, for ``lastmile sweep --suite``."""
