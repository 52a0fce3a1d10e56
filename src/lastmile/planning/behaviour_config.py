"""Parameters of Snow Lion's behaviour planner (:mod:`lastmile.planning.snow_lion_behaviour`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lastmile.core.errors import ConfigError


@dataclass(frozen=True, slots=True, kw_only=True)
class ScenarioProfile:
    """What one scenario tag sets (Snow Lion: "distinct configurations and constraints for each
    scenario": the lateral-offset options, the obstacle width inflation w_o, the maximum reference
    speed v_r). The paper does not publish its values; ours say why beside each profile.

    Attributes:
        offsets_m: the lateral-offset candidates D (rear axle, from the route centre line, left
            positive); those whose body would leave the lane are dropped where the lane is narrower.
        inflation_m: w_o, added on every side of a static obstacle's footprint and to a pedestrian's
            width in the clearance speed limit.
        reference_speed_mps: v_r, the most the reference route is driven at (None: the route's own
            limit, decision's).
    """

    offsets_m: tuple[float, ...]
    inflation_m: float
    reference_speed_mps: float | None = None

    def check(self, where: str) -> None:
        if not self.offsets_m or any(not math.isfinite(d) or abs(d) > 3.0 for d in self.offsets_m):
            raise ConfigError(f"{where}.offsets_m: expected 1+ offsets within 3 m, got {self.offsets_m}")
        if not (0.0 <= self.inflation_m <= 2.0):
            raise ConfigError(f"{where}.inflation_m: expected a value in [0, 2] m, got {self.inflation_m}")
        v = self.reference_speed_mps
        if v is not None and not (0.5 <= v <= 20.0 / 3.6 + 1e-9):
            raise ConfigError(f"{where}.reference_speed_mps: expected 0.5 to 5.56 m/s, got {v}")


def _common_road() -> ScenarioProfile:
    # Offsets inside the lane in steps of a quarter metre (about the in-lane room of a 2 m wide
    # shuttle in a 3.5 m lane on each side); w_o 0.5 m is the gap the potential field keeps
    # (PotentialFieldConfig.clearance_m), so this planner passes what that one passes.
    return ScenarioProfile(offsets_m=(-0.5, -0.25, 0.0, 0.25, 0.5), inflation_m=0.5)


def _parking_lot() -> ScenarioProfile:
    # "A parked car unexpectedly entering the AV's path": a wider inflation (a car door's width,
    # ~0.9 m) and 9 km/h, Snow Lion's Table 2 "high speed" mark, below which it drives over half the time.
    return ScenarioProfile(offsets_m=(-0.25, 0.0, 0.25), inflation_m=0.9, reference_speed_mps=2.5)


def _unprotected_intersection() -> ScenarioProfile:
    # No lateral moves inside a junction (other road users read the lane); the observation speed is
    # the same 9 km/h, from which the shuttle stops within 3.1 m at 1 m/s^2.
    return ScenarioProfile(offsets_m=(0.0,), inflation_m=0.5, reference_speed_mps=2.5)


@dataclass(frozen=True, slots=True, kw_only=True)
class ObservationConfig:
    """Snow Lion's observation areas at unprotected intersections (its Fig. 7a, green).

    Attributes:
        radius_m: the area: road users within this of the junction's middle are watched (a junction's
            width and a car's 2 s approach at 30 km/h beyond it).
        stop_back_m: the stop line is this far before the junction's first route record (front bumper).
        horizon_s: a watched road user's constant-velocity path is followed this far ahead (Snow Lion
            predicts with a constant velocity model).
        corridor_margin_m: it conflicts when that path enters the shuttle's lane widened by this, inside
            the junction's stretch of the route.
        min_speed_mps: road users slower than this are standing (not entering).
        clear_s: a stop for a conflict is released once none has been seen for this long (1 s: ten
            planning cycles, so one missed detection does not release it).
        approach_m: the observation speed applies from this far before the stop line.
    """

    radius_m: float = 30.0
    stop_back_m: float = 1.0
    horizon_s: float = 4.0
    corridor_margin_m: float = 0.5
    min_speed_mps: float = 0.5
    clear_s: float = 1.0
    approach_m: float = 15.0


@dataclass(frozen=True, slots=True, kw_only=True)
class BehaviourConfig:
    """Parameters of :class:`~lastmile.planning.snow_lion_behaviour.SnowLionBehaviourPlanner`,
    ``[stack.path.behaviour]``.

    Cost (Snow Lion's d_t = argmin J_s + J_d + J_o + J_dyn): J_s = w_s (1 - s_m(d) / s_max), J_d =
    w_d1 |d - d_0| + w_d2 |d|, J_o = w_o1 / c_avg + w_o2 / c_min, J_dyn = w_dyn when the candidate's path
    meets a moving road user's constant-velocity path (scaled down the later it meets it). The
    weights are ours: a blocked path (J_s) outweighs everything but a collision risk (J_dyn); an
    obstacle at the inflation's edge (0.5 m) moves the path a quarter metre away from it (J_o falls by
    0.67, J_d rises by 0.375), one 1.5 m off does not; w_d2 above w_d1 so that, with nothing beside
    it, the centre line is cheaper than staying off it.

    Attributes:
        common_road, parking_lot, unprotected_intersection: the scenario profiles.
        parking_lanelet_ids: route lanelets tagged parking lot by the user (besides the map's
            ``parking`` areas within ``parking_margin_m`` of the route).
        parking_margin_m: route records this close to a map ``parking`` area are in a parking lot (a
            car backing out of a space reaches about a car's length into the aisle).
        s_max_m: the sample distance s_max along each candidate.
        step_m: the candidates' sampling step.
        w_s, w_d1, w_d2, w_o1, w_o2, w_dyn: the weights.
        clearance_cap_m: clearances beyond this count as this (an obstacle far off costs nothing more).
        switch_delay_s: 1/f_p, the serpentine guard: a new target offset replaces the kept one only
            after it has been the best for this long (Snow Lion does not publish f_p; 1 s is ten of
            its 10 Hz interacting cycles), unless the kept one became blocked or unsafe.
        switch_margin: ... and only while it is cheaper than the kept one by this share of the kept cost.
        stop_gap_m: a truncated route stops the front this far before its end (the s-t planner's
            follow gap).
        dynamic_horizon_s: moving road users are followed this far (constant velocity).
        min_planning_speed_mps: the shuttle's timing along a candidate assumes at least this speed.
        observation: the observation areas.
    """

    common_road: ScenarioProfile = field(default_factory=_common_road)
    parking_lot: ScenarioProfile = field(default_factory=_parking_lot)
    unprotected_intersection: ScenarioProfile = field(default_factory=_unprotected_intersection)
    parking_lanelet_ids: tuple[int, ...] = ()
    parking_margin_m: float = 5.0
    s_max_m: float = 40.0
    step_m: float = 0.5
    w_s: float = 10.0
    w_d1: float = 0.5
    w_d2: float = 1.0
    w_o1: float = 0.5
    w_o2: float = 0.5
    w_dyn: float = 100.0
    clearance_cap_m: float = 3.0
    switch_delay_s: float = 1.0
    switch_margin: float = 0.1
    stop_gap_m: float = 3.0
    dynamic_horizon_s: float = 6.0
    min_planning_speed_mps: float = 1.0
    observation: ObservationConfig = field(default_factory=ObservationConfig)

    def __post_init__(self) -> None:
        self.common_road.check("stack.path.behaviour.common_road")
        self.parking_lot.check("stack.path.behaviour.parking_lot")
        self.unprotected_intersection.check("stack.path.behaviour.unprotected_intersection")
        for name in ("s_max_m", "step_m", "dynamic_horizon_s", "min_planning_speed_mps", "clearance_cap_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"stack.path.behaviour.{name}: expected a positive number, got {value}")
        for name in ("w_s", "w_d1", "w_d2", "w_o1", "w_o2", "w_dyn", "switch_delay_s", "switch_margin"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"stack.path.behaviour.{name}: expected a number >= 0, got {value}")
        if self.step_m > self.s_max_m / 4.0:
            raise ConfigError(
                f"stack.path.behaviour.step_m: expected at most s_max_m / 4 ({self.s_max_m / 4.0} m), "
                f"got {self.step_m}"
            )
