"""Snow Lion's behaviour planner on a straight road: costs, the 1/f_p guard, truncation, tags, observation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lastmile.core.config import from_mapping
from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, Trajectory
from lastmile.hdmap.layers import DRIVEWAY, UNCONTROLLED, SLayerDatabase
from lastmile.hdmap.model import HDMap, MapArea
from lastmile.planning.behaviour_config import BehaviourConfig, ScenarioProfile
from lastmile.planning.local_path import LocalPathConfig
from lastmile.planning.scenario_tags import ScenarioTag, polygon_distance_m, route_scenario_tags
from lastmile.planning.snow_lion_behaviour import SnowLionBehaviourPlanner, _Move
from lastmile.stack.stack_settings import StackSettings

HALF_W, BEHIND, AHEAD = 1.0, 0.85, 3.75
JUNCTION = (150, 160)
"""Route records of an uncontrolled junction (a driveway)."""
LOT = np.array([[220.0, 3.0], [260.0, 3.0], [260.0, 40.0], [220.0, 40.0]])
"""A parking area 1.25 m beside the lane's left edge, s 220-260."""


@pytest.fixture
def layers(straight_layers: SLayerDatabase, straight_map: HDMap) -> SLayerDatabase:
    n = len(straight_layers.s_m)
    road = np.zeros(n, dtype=np.int8)
    road[JUNCTION[0] : JUNCTION[1]] = DRIVEWAY
    kind = np.zeros(n, dtype=np.int8)
    kind[JUNCTION[0] : JUNCTION[1]] = UNCONTROLLED
    hdmap = dataclasses.replace(straight_map, areas=(MapArea(id=9, subtype="parking", polygon=LOT),))
    return dataclasses.replace(
        straight_layers,
        hdmap=hdmap,
        road_type=road,
        intersection_type=kind,
        lanelet_id=np.ones(n, dtype=np.int64),
    )


def _planner(layers: SLayerDatabase, **behaviour: object) -> SnowLionBehaviourPlanner:
    config = LocalPathConfig(behaviour=BehaviourConfig(**behaviour))  # type: ignore[arg-type]
    return SnowLionBehaviourPlanner(
        layers.centerline,
        HALF_W,
        config,
        body_behind_m=BEHIND,
        body_ahead_m=AHEAD,
        max_curvature_1pm=0.21,
        layers=layers,
    )


def _obstacle(
    s_m: float, d_m: float, *, v_s: float = 0.0, v_d: float = 0.0, length: float = 4.5, width: float = 1.8,
    cls: ObjectClass = ObjectClass.CAR, track_id: int = 1,
) -> RouteObstacle:  # fmt: skip
    return RouteObstacle(
        track_id=track_id, cls=cls, x_m=s_m, y_m=d_m, s_m=s_m, ds_m=0.0, d_m=d_m, v_s_mps=v_s, v_d_mps=v_d,
        length_m=length, width_m=width,
    )  # fmt: skip


def _decision(t_s: float = 0.0) -> BehaviourDecision:
    return BehaviourDecision(
        stamp=Stamp(round(t_s * 1e6)), state=BehaviourState.NORMAL_DRIVING, speed_limit_mps=5.0,
        stop_at_s_m=None, pullover_spot=None, merge_from_s_m=None, door_open=False, risk_track_id=-1,
        reason="",
    )  # fmt: skip


def _plan(
    p: SnowLionBehaviourPlanner, t_s: float, ego_s: float, obstacles: list[RouteObstacle]
) -> Trajectory:
    return p.plan(Stamp(round(t_s * 1e6)), ego_s, 0.0, _decision(t_s), obstacles)


def _held(p: SnowLionBehaviourPlanner) -> float:
    assert p._move is not None
    return p._move.to_d_m


# --- the cost terms ----------------------------------------------------------------------------------
def test_cost_terms_follow_the_papers_forms(layers: SLayerDatabase) -> None:
    p = _planner(layers)
    b = p.behaviour
    profile = b.common_road
    # A box standing across the lane 20.5 m ahead of the rear axle: every in-lane candidate meets it.
    wall = _obstacle(30.0, 0.0, length=1.0, width=3.0)
    cost = p.candidate_cost(10.0, 0.0, _Move(10.0, 0.0, 0.0, 1.0), [wall], profile)
    # The body's front reaches the inflated box when the rear axle is 30 - 0.5 - 0.5 - 3.75 m along.
    free = 30.0 - 0.5 - profile.inflation_m - AHEAD - 10.0
    assert cost.free_m == pytest.approx(math.ceil(free / b.step_m) * b.step_m, abs=1e-9)
    assert cost.j_s == pytest.approx(b.w_s * (1.0 - cost.free_m / b.s_max_m))
    # J_d = w_d1 |d - d0| + w_d2 |d|.
    moved = p.candidate_cost(10.0, 0.2, _Move(10.0, 0.2, -0.5, 10.0), [], profile)
    assert moved.j_d == pytest.approx(b.w_d1 * 0.7 + b.w_d2 * 0.5)
    assert moved.j_s == 0.0 and moved.j_o == 0.0 and moved.j_dyn == 0.0
    # J_o = w_o1 / c_avg + w_o2 / c_min: a car parked beside the lane, its edge 1.5 m from the body.
    beside = _obstacle(25.0, -(HALF_W + 1.5 + 0.9))
    clear = p.candidate_cost(10.0, 0.0, _Move(10.0, 0.0, 0.0, 1.0), [beside], profile)
    assert clear.j_o == pytest.approx(b.w_o1 / 1.5 + b.w_o2 / 1.5)
    assert clear.j_s == 0.0
    # J_dyn: a pedestrian crossing 15 m ahead meets the centre line's path, not a path 3 m away.
    crossing = _obstacle(27.0, -4.0, v_d=1.4, length=0.5, width=0.5, cls=ObjectClass.PEDESTRIAN)
    p._ego_speed_mps = 4.0
    hit = p.candidate_cost(10.0, 0.0, _Move(10.0, 0.0, 0.0, 1.0), [crossing], profile)
    assert 0.0 < hit.j_dyn <= b.w_dyn
    gone = _obstacle(27.0, 4.0, v_d=1.4, length=0.5, width=0.5, cls=ObjectClass.PEDESTRIAN)
    assert p.candidate_cost(10.0, 0.0, _Move(10.0, 0.0, 0.0, 1.0), [gone], profile).j_dyn == 0.0


def test_candidates_leaving_the_lane_are_infeasible(layers: SLayerDatabase) -> None:
    p = _planner(layers)
    profile = ScenarioProfile(offsets_m=(0.0, 1.0), inflation_m=0.5)
    out = p.candidate_cost(10.0, 0.0, _Move(10.0, 0.0, 1.0, 5.0), [], profile)  # body edge 2.0 > 1.65
    assert math.isinf(out.total)


def test_passes_an_obstacle_partly_in_the_lane_with_the_inflation_kept(layers: SLayerDatabase) -> None:
    p = _planner(layers)
    bin_ = _obstacle(60.0, -1.75, length=1.0, width=1.0)  # half in the lane on the right
    traj = None
    for k in range(30):  # the target changes only after the 1/f_p delay
        traj = _plan(p, 0.1 * k, 20.0, [bin_])
    assert traj is not None and not traj.truncated
    target = _held(p)
    assert target > 0.0, "it did not move away from the obstacle"
    # The body's right side keeps the inflation from the obstacle's left edge.
    assert target - HALF_W >= -1.75 + 0.5 + p.behaviour.common_road.inflation_m - 1e-9


# --- the 1/f_p guard ----------------------------------------------------------------------------------
def test_a_better_offset_replaces_the_kept_one_only_after_the_delay(layers: SLayerDatabase) -> None:
    p = _planner(layers, switch_delay_s=1.0)
    beside = _obstacle(60.0, -2.4, length=4.5, width=1.8)  # parked beside the lane: nicer further left
    for k in range(5):
        _plan(p, 0.1 * k, 20.0, [])
    assert _held(p) == 0.0
    t_switch = None
    for k in range(5, 40):
        _plan(p, 0.1 * k, 20.0, [beside])
        if _held(p) != 0.0 and t_switch is None:
            t_switch = 0.1 * k
    assert t_switch is not None, "the cheaper offset was never taken"
    assert t_switch == pytest.approx(0.5 + 1.0, abs=0.051), t_switch  # first best at 0.5 s, kept 1 s


def test_a_blocked_kept_offset_is_left_at_once(layers: SLayerDatabase) -> None:
    p = _planner(layers, switch_delay_s=5.0)
    for k in range(3):
        _plan(p, 0.1 * k, 20.0, [])
    # A box appears on the right half of the lane: the centre line is now blocked, a left offset not.
    box = _obstacle(45.0, -1.6, length=1.0, width=0.6)
    _plan(p, 0.3, 20.0, [box])
    assert _held(p) > 0.0, "a blocked target must not wait for the serpentine guard"


def test_an_equally_good_offset_does_not_make_it_weave(layers: SLayerDatabase) -> None:
    """Two obstacles on either side alternating in the tracker's view: the kept choice holds."""
    p = _planner(layers, switch_delay_s=1.0)
    left = _obstacle(60.0, 2.5, length=4.5, width=1.8, track_id=1)
    right = _obstacle(60.0, -2.5, length=4.5, width=1.8, track_id=2)
    held = []
    for k in range(40):
        _plan(p, 0.1 * k, 20.0, [left] if (k // 3) % 2 else [right])
        held.append(_held(p))
    assert len(set(held)) <= 2, held  # at most one move, never back and forth


# --- truncation ---------------------------------------------------------------------------------------
def test_no_free_candidate_truncates_the_route_before_the_obstacle(layers: SLayerDatabase) -> None:
    p = _planner(layers)
    wall = _obstacle(50.0, 0.0, length=1.0, width=3.5)
    traj = _plan(p, 0.0, 20.0, [wall])
    assert traj.truncated
    assert traj.stop_at_route_s_m is not None
    rear_edge = 50.0 - 0.5 - p.behaviour.common_road.inflation_m
    # Within one sampling step past the inflated rear edge, less the stop gap.
    step = p.behaviour.step_m
    assert (
        rear_edge - p.behaviour.stop_gap_m
        <= traj.stop_at_route_s_m
        <= rear_edge - p.behaviour.stop_gap_m + step
    )
    free = _plan(p, 0.1, 20.0, [])
    assert not free.truncated and free.stop_at_route_s_m is None


# --- scenario tags, reference speed, observation ---------------------------------------------------------
def test_route_records_are_tagged_from_the_map_and_the_configuration(layers: SLayerDatabase) -> None:
    tags = route_scenario_tags(layers, parking_margin_m=5.0)
    assert set(tags[JUNCTION[0] : JUNCTION[1]]) == {ScenarioTag.UNPROTECTED_INTERSECTION}
    assert set(tags[225:255]) == {ScenarioTag.PARKING_LOT}
    assert set(tags[:140]) == {ScenarioTag.COMMON_ROAD}
    assert set(tags[270:]) == {ScenarioTag.COMMON_ROAD}
    by_id = route_scenario_tags(layers, parking_margin_m=0.5, parking_lanelet_ids=(1,))
    assert by_id[10] == ScenarioTag.PARKING_LOT  # lanelet 1 is the straight road


def test_polygon_distance_is_zero_inside_and_euclidean_outside() -> None:
    d = polygon_distance_m(np.array([[240.0, 10.0], [240.0, 0.0], [262.0, 3.0]]), LOT)
    assert d == pytest.approx([0.0, 3.0, 2.0])


def test_reference_speed_drops_towards_the_junction_and_the_lot(layers: SLayerDatabase) -> None:
    p = _planner(layers)
    v_obs = p.behaviour.unprotected_intersection.reference_speed_mps
    assert v_obs is not None
    far = _plan(p, 0.0, 40.0, [])
    near = _plan(p, 0.1, 125.0, [])
    inside = _plan(p, 0.2, 150.0, [])
    lot = _plan(p, 0.3, 230.0, [])
    assert math.isinf(far.speed_limit_mps)
    assert v_obs < near.speed_limit_mps < 6.0
    assert inside.speed_limit_mps == pytest.approx(v_obs)
    assert lot.speed_limit_mps == pytest.approx(p.behaviour.parking_lot.reference_speed_mps)


def test_observation_area_stops_at_the_line_for_a_car_coming_across(layers: SLayerDatabase) -> None:
    p = _planner(layers)
    line = JUNCTION[0] - p.behaviour.observation.stop_back_m
    ego = 130.0  # front 16.25 m before the line, slow enough to stop
    crossing = _obstacle(155.0, 12.0, v_d=-5.0, track_id=7)
    stopped = _plan(p, 0.0, ego, [crossing])
    assert stopped.stop_at_route_s_m == pytest.approx(line)
    # A car ahead in the lane going the same way is followed, not yielded to.
    along = _obstacle(150.0, 0.0, v_s=5.0, track_id=8)
    p2 = _planner(layers)
    assert _plan(p2, 0.0, ego, [along]).stop_at_route_s_m is None
    # Once the crossing car has gone, the stop is released after ``clear_s``.
    assert _plan(p, 0.5, ego, []).stop_at_route_s_m == pytest.approx(line)
    assert _plan(p, 1.2, ego, []).stop_at_route_s_m is None


# --- configuration --------------------------------------------------------------------------------------
def test_the_planner_and_its_parameters_load_from_a_run_configuration() -> None:
    s = from_mapping(
        StackSettings,
        {"planner": "snow_lion_behaviour", "path": {"behaviour": {"parking_lot": {"offsets_m": [0.0],
         "inflation_m": 1.0, "reference_speed_mps": 2.0}}}},
        "stack",
    )  # fmt: skip
    assert s.path.behaviour is not None and s.path.behaviour.parking_lot.inflation_m == 1.0
    with pytest.raises(ConfigError, match=r"stack\.path\.behaviour: unknown key 'f_p'"):
        from_mapping(StackSettings, {"path": {"behaviour": {"f_p": 2.0}}}, "stack")
    with pytest.raises(ConfigError, match="offsets_m: expected 1\\+ offsets within 3 m"):
        ScenarioProfile(offsets_m=(), inflation_m=0.5).check("x")
    with pytest.raises(ConfigError, match="planner: expected one of"):
        from_mapping(StackSettings, {"planner": "snow_lion"}, "stack")
