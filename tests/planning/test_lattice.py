"""aUToronto's lattice planner on a straight two-lane road: the lattice, A*'s choices, pruning, blockage."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, PassRequest
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.model import HDMap, LaneletInfo
from lastmile.hdmap.routing import campus_shuttle_loop
from lastmile.planning.lattice_config import LatticeConfig
from lastmile.planning.lattice_graph import Hermite5, LaneKind, LatticeGraph, VehicleBody
from lastmile.planning.lattice_planner import LatticePlanner
from lastmile.planning.lattice_search import LatticeSearch, SearchObstacle, SearchRequest
from lastmile.planning.local_path import LocalPathConfig

LANE_W = 3.5
LENGTH_M = 400.0
BODY = VehicleBody(behind_m=0.85, ahead_m=3.75, half_width_m=1.0, max_curvature_1pm=0.21)


def _lane(lid: int, y_right: float, backwards: bool = False, **kw: object) -> LaneletInfo:
    xs = np.array([LENGTH_M, 0.0]) if backwards else np.array([0.0, LENGTH_M])
    right, left = (y_right + LANE_W, y_right) if backwards else (y_right, y_right + LANE_W)
    return LaneletInfo(
        id=lid,
        centerline=Polyline(np.c_[xs, np.full(2, y_right + LANE_W / 2)]),
        left=Polyline(np.c_[xs, np.full(2, left)]),
        right=Polyline(np.c_[xs, np.full(2, right)]),
        speed_limit_mps=20 / 3.6,
        **kw,  # type: ignore[arg-type]
    )


def _layers(left: str) -> SLayerDatabase:
    """The route lane (id 1, centre y = 0, eastbound) and, on its left, ``left``: "sibling" (an
    eastbound lane a lane change may enter), "solid" (eastbound, no change allowed), "bay" (a bus
    bay), "opposite" (westbound)."""
    lanes = {1: _lane(1, -LANE_W / 2)}
    neighbours: dict[int, tuple[int, ...]] = {}
    if left == "opposite":
        lanes[2] = _lane(2, LANE_W / 2, backwards=True)
    else:
        lanes[2] = _lane(2, LANE_W / 2, bus_stop_id="S9" if left == "bay" else "")
        if left != "solid":
            neighbours = {1: (2,), 2: (1,)}
    hdmap = HDMap(name="two lanes", lanelets=lanes, successor_ids={}, neighbour_ids=neighbours)
    n = int(LENGTH_M) + 1
    return SLayerDatabase(
        hdmap=hdmap,
        centerline=Polyline(np.array([[0.0, 0.0], [LENGTH_M, 0.0]])),
        step_m=1.0,
        s_m=np.arange(n, dtype=float),
        speed_limit_mps=np.full(n, 20 / 3.6),
        lane_left_d_m=np.full(n, LANE_W / 2),
        lane_right_d_m=np.full(n, -LANE_W / 2),
        curb_right_d_m=np.full(n, -LANE_W / 2),
        road_type=np.zeros(n, dtype=np.int8),
        lanelet_id=np.ones(n, dtype=np.int64),
    )


def _graph(
    left: str = "opposite", config: LatticeConfig | None = None, drivable: object = None
) -> LatticeGraph:
    layers = _layers(left)
    return LatticeGraph(layers, layers.centerline, BODY, config or LatticeConfig(), drivable)  # type: ignore[arg-type]


def _request(
    obstacles: tuple[SearchObstacle, ...] = (), allow_opposite: bool = False, **kw: object
) -> SearchRequest:
    fields = {
        "ego_s_m": 50.0,
        "start": (0.0, 0.0, 0.0),
        "allow_opposite": allow_opposite,
        "obstacles": obstacles,
        "speed_mps": 4.0,
        "clearance_m": 1.0,
        "min_clearance_m": 0.5,
        "in_lane_clearance_m": 0.5,
        "lane_half_width_m": LANE_W / 2,
    }
    fields.update(kw)
    return SearchRequest(**fields)  # type: ignore[arg-type]


PARKED = SearchObstacle(s_m=100.0, d_m=0.0, length_m=4.5, width_m=1.8)
"""A car parked in the middle of the route lane: no room beside it in the lane."""
PASSED_D_M = 0.9 + 1.0 + 1.0
"""The least rear-axle offset beside it: its left edge, the 1 m clearance, half the body."""


# --- the lattice ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("left", "kinds"),
    [
        ("opposite", [LaneKind.OWN, LaneKind.OPPOSITE]),
        ("sibling", [LaneKind.OWN, LaneKind.SIBLING]),
        ("solid", [LaneKind.OWN]),
        ("bay", [LaneKind.OWN]),
    ],
)
def test_each_station_has_a_node_on_the_route_lane_and_on_each_lanelet_a_lane_change_may_use(left, kinds):
    graph = _graph(left)
    assert graph.spacing_m == 12.0 and graph.n_stations == 34
    for station in graph.nodes:
        assert [n.kind for n in station] == kinds
        assert station[0].d_m == 0.0
        if len(station) > 1:
            assert station[1].d_m == pytest.approx(LANE_W, abs=1e-9)
            assert station[1].lanelet_id == 2


def test_lane_changes_span_as_many_stations_as_the_steering_needs_and_keeps_one():
    graph = _graph("opposite", LatticeConfig(max_span_stations=3))
    own = graph.edges[5][0]
    assert sorted((e.to_slot, e.span) for e in own) == [(0, 1), (1, 1), (1, 2), (1, 3)]
    # 3.5 m over 12 m bends at 10/sqrt(3) x 3.5 / 144 = 0.14 /m, under 0.8 x 0.21; a tighter
    # steering drops it.
    tight_body = dataclasses.replace(BODY, max_curvature_1pm=0.1)
    tight = LatticeGraph(_layers("opposite"), _layers("opposite").centerline, tight_body, LatticeConfig())
    assert sorted((e.to_slot, e.span) for e in tight.edges[5][0]) == [(0, 1), (1, 2), (1, 3)]
    for edge in own:
        assert edge.peak_curvature_1pm <= 0.8 * BODY.max_curvature_1pm


def test_edges_whose_body_leaves_the_road_are_not_in_the_lattice():
    """The opposite lane is paved only up to y = 4.0 at x 100-160: a body on its centre (left side at
    4.5) does not fit there, so no keep of the opposite lane touches that stretch; elsewhere all do."""

    def drivable(xy: np.ndarray) -> np.ndarray:
        narrow = (xy[:, 0] > 100.0) & (xy[:, 0] < 160.0)
        return np.where(narrow, xy[:, 1] < 4.0, xy[:, 1] < 5.25) & (xy[:, 1] > -1.75)

    graph = _graph("opposite", drivable=drivable)
    for k in range(graph.n_stations - 1):
        s0, s1 = graph.station_s_m(k), graph.station_s_m(k + 1)
        touches = s1 + BODY.ahead_m > 100.0 and s0 - BODY.behind_m < 160.0
        keeps = [e for e in graph.edges[k][1] if e.to_slot == 1 and e.span == 1]
        assert (not keeps) if touches else len(keeps) == 1, (s0, s1)
    assert len(graph.edges[9][0]) == 1, "from x = 108 only the route lane's keep is left"


def test_quintic_hermite_edges_match_position_slope_and_curvature_at_both_ends():
    start, end = (0.3, 0.05, -0.01), (3.5, 0.0, 0.0)
    curve = Hermite5.between(40.0, 64.0, start, end)
    for s, state in ((40.0, start), (64.0, end)):
        got = [float(curve.state(np.array([s]), order)[0]) for order in range(3)]
        assert got == pytest.approx(list(state), abs=1e-9)


def test_the_path_is_continuous_in_position_heading_and_curvature_through_every_node():
    graph = _graph("opposite")
    search = LatticeSearch(graph)
    result = search.search(_request((PARKED,), allow_opposite=True, start=(0.2, 0.01, 0.0)))
    assert result.path is not None and result.path.leaves_route_lane
    curves = result.path.curves
    for a, b in itertools.pairwise(curves):
        join = a.s0_m + a.length_m
        assert join == pytest.approx(b.s0_m)
        for order in range(3):
            left = float(a.state(np.array([join]), order)[0])
            right = float(b.state(np.array([join]), order)[0])
            assert left == pytest.approx(right, abs=1e-9), (order, join)


# --- A* ---------------------------------------------------------------------------------------------
def test_with_nothing_in_the_way_the_path_keeps_the_route_lane():
    result = LatticeSearch(_graph("sibling")).search(_request())
    assert result.path is not None
    assert not result.path.leaves_route_lane
    assert np.abs(result.path.d_at(np.arange(50.0, 120.0))).max() == 0.0


def test_a_car_blocking_the_lane_is_passed_by_the_opposite_lane_when_allowed_then_the_path_returns():
    result = LatticeSearch(_graph("opposite")).search(_request((PARKED,), allow_opposite=True))
    assert result.path is not None
    d = result.path.d_at(np.array([60.0, 100.0, 130.0]))
    assert d[0] == pytest.approx(0.0, abs=0.05)
    assert PASSED_D_M <= d[1] <= LANE_W  # beside the car: out in the opposite lane
    assert d[2] < 0.05  # back in its lane after it
    assert result.path.kinds[-1] == LaneKind.OWN


def test_a_sibling_lane_is_used_around_a_blockage_without_decisions_pass():
    result = LatticeSearch(_graph("sibling")).search(_request((PARKED,)))
    assert result.path is not None
    assert LaneKind.SIBLING in result.path.kinds
    assert float(result.path.d_at(np.array([100.0]))[0]) >= PASSED_D_M


def test_a_car_leaving_room_in_the_lane_is_nudged_past_not_changed_lane_for():
    """A bin at the lane's right edge (its left side at -0.9 m) leaves 1.65 + 0.9 - 0.5 = 2.05 m of
    the lane for the 2 m body with the potential field's 0.5 m: the route lane is kept (and nudged)."""
    at_edge = dataclasses.replace(PARKED, d_m=-1.3, width_m=0.8, length_m=0.8)
    result = LatticeSearch(_graph("sibling")).search(_request((at_edge,)))
    assert result.path is not None and not result.path.leaves_route_lane


def test_a_lane_change_costs_more_than_the_route_lane_so_an_occupied_sibling_is_no_reason():
    """A car in the sibling lane beside the route changes nothing; the route lane is the cheaper."""
    beside = dataclasses.replace(PARKED, d_m=LANE_W)
    graph = _graph("sibling")
    result = LatticeSearch(graph).search(_request((beside,)))
    assert result.path is not None and not result.path.leaves_route_lane
    # and the penalty is what keeps it there: free of it, a lane change is no dearer than the lane
    free = LatticeSearch(_graph("sibling", LatticeConfig(w_lane_change=0.0, w_deviation=0.0)))
    cost_free = free.search(_request()).path
    assert cost_free is not None and result.path.cost > cost_free.cost


def test_the_opposite_lane_is_never_used_without_decisions_approval_a_full_blockage_stops_before_it():
    result = LatticeSearch(_graph("opposite")).search(_request((PARKED,), allow_opposite=False))
    assert result.path is None
    assert result.blocked_at_s_m == pytest.approx(PARKED.rear_s_m)


def test_both_lanes_blocked_is_a_full_blockage():
    other = dataclasses.replace(PARKED, s_m=102.0, d_m=LANE_W)
    result = LatticeSearch(_graph("opposite")).search(_request((PARKED, other), allow_opposite=True))
    assert result.path is None
    assert result.blocked_at_s_m == pytest.approx(PARKED.rear_s_m)


def test_an_oncoming_car_prunes_the_opposite_lane_where_it_will_be():
    """A car coming at 6 m/s from 160 m: timed at 4 m/s, it is beside the parked car when the shuttle
    would be; the pass is pruned, and the stretch is a blockage."""
    oncoming = SearchObstacle(s_m=160.0, d_m=LANE_W, length_m=4.5, width_m=1.8, v_s_mps=-6.0)
    result = LatticeSearch(_graph("opposite")).search(_request((PARKED, oncoming), allow_opposite=True))
    assert result.path is None


# --- pruning ----------------------------------------------------------------------------------------
def test_obstacles_are_checked_only_within_the_bfs_neighbourhood_of_the_shuttle():
    """The car 50 m ahead lies beyond one edge's reach: with prune_depth 1 the lattice beyond is not
    checked (the path runs through it, to be re-checked on the next cycles); with 5 it is avoided."""
    near = LatticeSearch(_graph("opposite", LatticeConfig(prune_depth=1)))
    shallow = near.search(_request((PARKED,), allow_opposite=True))
    assert shallow.path is not None and not shallow.path.leaves_route_lane
    deep = LatticeSearch(_graph("opposite", LatticeConfig(prune_depth=5))).search(
        _request((PARKED,), allow_opposite=True)
    )
    assert deep.path is not None and deep.path.leaves_route_lane
    assert shallow.checked_edges < deep.checked_edges


def test_the_configuration_is_checked():
    with pytest.raises(ConfigError, match="station_spacing_m"):
        LatticeConfig(station_spacing_m=2.0)
    with pytest.raises(ConfigError, match="prune_depth"):
        LatticeConfig(prune_depth=0)


# --- the planner ------------------------------------------------------------------------------------
def _car(s_m: float = 100.0, d_m: float = 0.0) -> RouteObstacle:
    return RouteObstacle(
        track_id=1, cls=ObjectClass.CAR, x_m=s_m, y_m=d_m, s_m=s_m, ds_m=0.0, d_m=d_m,
        v_s_mps=0.0, v_d_mps=0.0, length_m=4.5, width_m=1.8,
    )  # fmt: skip


def _decision(request: PassRequest | None) -> BehaviourDecision:
    return BehaviourDecision(
        stamp=Stamp(0),
        state=BehaviourState.NORMAL_DRIVING,
        speed_limit_mps=4.0,
        stop_at_s_m=None,
        pullover_spot=None,
        merge_from_s_m=None,
        door_open=False,
        risk_track_id=-1,
        reason="",
        pass_request=request,
    )


def _planner() -> LatticePlanner:
    layers = _layers("opposite")
    return LatticePlanner(
        layers.centerline, 1.0, LocalPathConfig(), body_behind_m=0.85, body_ahead_m=3.75,
        max_curvature_1pm=0.21, layers=layers,
    )  # fmt: skip


def _request_pass(approved: bool) -> PassRequest:
    return PassRequest(
        track_id=1, start_s_m=97.75, end_s_m=102.25, left_d_m=0.9, max_d_m=5.25, lookout_d_m=0.3,
        wait_s_m=77.75, approved=approved,
    )  # fmt: skip


def test_the_planner_truncates_and_stops_before_a_full_blockage():
    trajectory = _planner().plan(Stamp(0), 50.0, 0.0, _decision(None), [_car()])
    assert trajectory.truncated
    assert trajectory.stop_at_route_s_m == pytest.approx(97.75 - 3.0)
    assert np.abs(trajectory.points[:, 1]).max() < 0.05  # the path itself stays in the lane


def test_the_planner_passes_by_the_opposite_lane_once_decision_approves():
    planner = _planner()
    waiting = planner.plan(Stamp(0), 50.0, 0.0, _decision(_request_pass(False)), [_car()])
    assert waiting.truncated and np.abs(waiting.points[:, 1]).max() < 0.35  # the look-out offset
    passing = planner.plan(Stamp(0), 50.0, 0.0, _decision(_request_pass(True)), [_car()])
    assert not passing.truncated and passing.stop_at_route_s_m is None
    beside = np.abs(passing.points[:, 0] - 100.0) < 3.0
    assert PASSED_D_M - 0.05 <= passing.points[beside, 1].min() <= LANE_W + 0.05


def test_blocked_out_of_its_lane_the_planner_holds_the_path_being_driven_and_stops():
    """Beside the parked car in the opposite lane, a car standing ahead there blocks both lanes: the
    path is not swung back towards the blocked lane; the shuttle stops 3 m before the first obstacle
    that blocked an edge."""
    planner = _planner()
    first = planner.plan(Stamp(0), 50.0, 0.0, _decision(_request_pass(True)), [_car()])
    assert not first.truncated
    ahead = dataclasses.replace(_car(s_m=112.0, d_m=LANE_W), track_id=2)
    committed = dataclasses.replace(_request_pass(True), committed=True)
    # the rear axle at 96 m, where the last path has it out in the opposite lane
    at = float(planner.last_path.d_at(np.array([96.0]))[0]) if planner.last_path else 0.0
    assert at > 2.0
    held = planner.plan(Stamp(100_000), 96.0, at, _decision(committed), [_car(), ahead])
    assert held.truncated and held.stop_at_route_s_m is not None
    near = np.abs(held.points[:, 0] - 100.0) < 2.0
    assert held.points[near, 1].min() > 2.0, "the path stays out beside the parked car"


def test_on_the_campus_map_the_opposite_lane_is_found_beside_the_route_and_bays_are_left_out():
    """The campus loop (Lanelet2 file): the oncoming lane's centre 3.5 m left of the route at every
    station of the bottom straight (route s 350-542), and no sibling node at S1's bay (s 500)."""
    hdmap = load_campus_map()
    layers = SLayerDatabase.build(hdmap, campus_shuttle_loop(hdmap), step_m=1.0, closed=True)
    graph = LatticeGraph(layers, layers.centerline, BODY, LatticeConfig())
    assert graph.route.closed and 10.0 <= graph.spacing_m <= 15.0
    assert graph.n_stations * graph.spacing_m == pytest.approx(layers.centerline.length_m)
    straight = [k for k in range(graph.n_stations) if 350.0 <= graph.station_s_m(k) <= 542.0]
    for k in straight:
        kinds = [n.kind for n in graph.nodes[k]]
        assert kinds == [LaneKind.OWN, LaneKind.OPPOSITE], (graph.station_s_m(k), kinds)
        assert graph.nodes[k][1].d_m == pytest.approx(3.5, abs=0.05)
    bay = layers.hdmap.neighbours(int(layers.lanelet_id[layers.record_index(500.0)]))
    assert bay, "S1's bay is a Lanelet2 neighbour of the route lane there"
    assert all(n.lanelet_id not in bay for k in straight for n in graph.nodes[k])
