"""The road's edges along the route, the body placed along a path, and the lift that keeps it on the road."""

import math

import numpy as np
import pytest

from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState
from lastmile.hdmap.corner_rounding import max_curvature_per_m
from lastmile.planning.local_path import LocalPathConfig, LocalPathPlanner, _tent_lift_m
from lastmile.planning.road_edge import (
    STATION_M,
    BodyPlacement,
    RoadEdges,
    body_overhang_m,
    path_xy,
    rear_steers,
)

G = VehicleGeometry()
BODY = BodyPlacement(
    behind_m=G.rear_overhang_m,
    ahead_m=G.length_m - G.rear_overhang_m,
    half_width_m=G.width_m / 2.0,
    wheelbase_m=G.wheelbase_m,
)
STRAIGHT = Polyline(np.array([[0.0, 0.0], [200.0, 0.0]]))
NARROWS_AT_X_M = 100.0


def _narrowing_road(pts: np.ndarray) -> np.ndarray:
    """2.3 m either side of the x axis, the right side 1.6 m from x = 100 on (a kerb coming in)."""
    pts = np.asarray(pts).reshape(-1, 2)
    right = np.where(pts[:, 0] < NARROWS_AT_X_M, -2.3, -1.6)
    return (pts[:, 1] >= right) & (pts[:, 1] <= 2.3) & (pts[:, 0] >= -10.0) & (pts[:, 0] <= 210.0)


def _decision(
    state: BehaviourState, spot: SE2 | None = None, merge_from: float | None = None
) -> BehaviourDecision:
    return BehaviourDecision(
        stamp=Stamp(0),
        state=state,
        speed_limit_mps=5.0,
        stop_at_s_m=None,
        pullover_spot=spot,
        merge_from_s_m=merge_from,
        door_open=False,
        risk_track_id=-1,
        reason="",
    )


def test_edges_are_found_to_two_centimetres_either_side():
    edges = RoadEdges(STRAIGHT, _narrowing_road)
    right = edges.right_d_m(np.array([50.0, 150.0]))
    left = edges.left_d_m(np.array([50.0, 150.0]))
    assert right == pytest.approx([-2.3, -1.6], abs=0.02)
    assert left == pytest.approx([2.3, 2.3], abs=0.02)


def test_no_edge_where_the_route_itself_is_off_the_road_or_a_curb_is_mapped():
    edges = RoadEdges(STRAIGHT, lambda p: _narrowing_road(p) & (np.asarray(p).reshape(-1, 2)[:, 0] > 20.0))
    assert np.isnan(edges.right_d_m(np.array([10.0])))[0]
    curbed = RoadEdges(STRAIGHT, _narrowing_road, mapped_curb=lambda s: np.where(s > 140.0, -1.6, np.nan))
    out = curbed.right_d_m(np.array([50.0, 150.0]))
    assert out[0] == pytest.approx(-2.3, abs=0.02) and np.isnan(out[1])


def test_the_front_corner_swings_out_beyond_the_rear_axle_line_on_a_bend():
    """A left arc of 5 m radius: the rear axle 1.0 m inside the right edge's 2.4 m clears it by
    0.4 m in route offsets, yet the front corner, 3.75 m ahead on the tangent, is over it."""
    theta = np.linspace(-math.pi / 2, math.pi / 2, 400)
    arc = np.c_[5.0 * np.cos(theta), 5.0 * np.sin(theta) + 5.0]
    route = Polyline(np.vstack([[[-30.0, 0.0]], arc, [[-30.0, 10.0]]]))
    centre = np.array([0.0, 5.0])

    def road(pts: np.ndarray) -> np.ndarray:
        pts = np.asarray(pts).reshape(-1, 2)
        r = np.hypot(*(pts - centre).T)
        on_arc = (pts[:, 0] >= 0.0) & (r <= 7.4) & (r >= 1.0)
        on_arms = (pts[:, 0] < 0.0) & (((pts[:, 1] >= -2.4) & (pts[:, 1] <= 2.4)) | (pts[:, 1] >= 7.6))
        return on_arc | on_arms

    edges = RoadEdges(route, road)
    s_apex = 30.0 + 0.5 * math.pi * 5.0
    s = np.arange(s_apex - 8.0, s_apex + 0.01, STATION_M)
    d = np.full_like(s, -1.0)
    (over,) = body_overhang_m(route, edges, BODY, s, d, margin_m=0.0)
    assert over.max() > 0.3
    steered = BodyPlacement(
        behind_m=BODY.behind_m,
        ahead_m=BODY.ahead_m,
        half_width_m=BODY.half_width_m,
        wheelbase_m=BODY.wheelbase_m,
        rear_steer_above_1pm=max_curvature_per_m(G),
    )
    (over_steered,) = body_overhang_m(route, edges, steered, s, d, margin_m=0.0)
    assert over_steered.max() < over.max() - 0.3  # the wheelbase centre on the path swings less
    assert rear_steers(route, np.array([s_apex]), G.wheelbase_m, BODY.ahead_m, max_curvature_per_m(G))[0]
    assert not rear_steers(route, np.array([10.0]), G.wheelbase_m, BODY.ahead_m, max_curvature_per_m(G))[0]


def test_the_merge_lifts_off_a_kerb_that_comes_in_and_the_pullover_is_left_to_its_stop():
    """Held at the kerb (d -1.2) while traffic passes (the merge restarts where it stands, s 95), the
    merge's body would run its right side along -2.2 into the road narrowing to -1.6 from s 100 (the
    BITS loop's CP: the shuttle crept out along the kerb and its corner left the road): the planned
    path is lifted off the edge, and not lowered anywhere."""
    config = LocalPathConfig()
    planner = LocalPathPlanner(
        STRAIGHT, G.width_m / 2.0, config, None, BODY.behind_m, BODY.ahead_m, _narrowing_road, BODY
    )
    plain = LocalPathPlanner(
        STRAIGHT, G.width_m / 2.0, LocalPathConfig(keep_on_road=False), None, BODY.behind_m, BODY.ahead_m
    )
    spot = SE2(80.0, -1.2, 0.0)  # where it stood; the merge restarted 15 m on
    merging = _decision(BehaviourState.MERGING, spot=spot, merge_from=95.0)
    s = np.arange(70.0, 150.0, 2.0)
    lifted = planner.offsets_m(s, merging, [], -1.2)
    before = plain.offsets_m(s, merging, [], -1.2)
    grid = np.arange(70.0, 148.0, STATION_M)
    edges = RoadEdges(STRAIGHT, _narrowing_road)
    (over_before,) = body_overhang_m(STRAIGHT, edges, BODY, grid, np.interp(grid, s, before), 0.08)
    (over_after,) = body_overhang_m(STRAIGHT, edges, BODY, grid, np.interp(grid, s, lifted), 0.08)
    assert over_before.max() > 0.3
    assert over_after.max() < 0.01
    assert np.all(lifted >= before - 1e-12)
    # The lift begins no further back than its slope and rounding need (held 4 m + rounded 4 m +
    # rising at 1:5 to the ~0.6 m overhang at the front's s 100 - 3.75 m): 20 m back it is nil.
    assert lifted[0] == pytest.approx(before[0])
    # The pull-over is not lifted (its stop's placement governs the spot; see _on_the_road).
    pulling = _decision(BehaviourState.PULLOVER, spot=SE2(99.0, -1.2, 0.0))
    s2 = np.arange(40.0, 110.0, 2.0)
    assert planner.offsets_m(s2, pulling, [], 0.0) == pytest.approx(plain.offsets_m(s2, pulling, [], 0.0))
    xy, _ = path_xy(STRAIGHT, grid, np.interp(grid, s, lifted))
    assert np.all(np.isfinite(xy))


def test_lift_covers_every_need_exactly_with_bounded_slope():
    need = np.zeros(161)
    need[60] = 0.05
    need[100:120] = 0.4
    lift = _tent_lift_m(need, STATION_M, 0.2, 8.0)
    assert np.all(lift >= need - 1e-12)
    assert lift[110] == pytest.approx(0.4)  # a wide need is lifted by itself, not more
    assert np.max(np.abs(np.diff(lift))) / STATION_M <= 0.2 + 1e-9
    assert lift[0] == 0.0 and lift[-1] == 0.0
    assert np.all(_tent_lift_m(np.zeros(10), STATION_M, 0.2, 8.0) == 0.0)
