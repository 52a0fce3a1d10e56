import numpy as np
import pytest

from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState
from lastmile.planning.bezier import cubic_bezier, lateral_transition_m, smooth_through
from lastmile.planning.local_path import LocalPathPlanner, rounded_floor_m
from lastmile.planning.potential_field import PotentialFieldConfig, nudge_offsets_m

ROUTE = Polyline(np.array([[0.0, 0.0], [500.0, 0.0]]))


def _decision(state=BehaviourState.NORMAL_DRIVING, spot=None, merge_from=None):
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


def _static(s, d, width=1.0, length=1.0):
    return RouteObstacle(1, ObjectClass.UNKNOWN, s, d, s, s, d, 0.0, 0.0, length, width)


def test_transition_is_level_at_both_ends_and_monotone():
    s = np.linspace(0, 30, 301)
    d = lateral_transition_m(s, 10.0, 26.0, 0.0, -3.6)
    assert d[0] == 0.0 and d[-1] == -3.6
    assert np.all(np.diff(d) <= 1e-12)
    slope = np.diff(d) / np.diff(s)
    assert abs(slope[100]) < 0.05 and abs(slope[259]) < 0.05  # near s0 and s1


def test_bezier_chain_passes_through_its_waypoints():
    way = np.array([[0.0, 0.0], [5.0, 1.0], [10.0, 0.0], [15.0, -1.0]])
    chain = smooth_through(way, samples_per_segment=4)
    for p in way:
        assert np.min(np.hypot(*(chain - p).T)) < 1e-9


def test_field_nudges_left_around_an_obstacle_partly_in_the_lane_and_returns():
    s = np.arange(0.0, 100.0, 1.0)
    # Left edge at d = -1.1; keeping 0.5 m with a 1.0 m half width puts the centre at 0.4.
    off = nudge_offsets_m(s, [_static(50.0, -1.6, width=1.0)], 1.0, 1.75, -1.75, PotentialFieldConfig())
    assert off[50] == pytest.approx(-1.6 + 0.5 + 0.5 + 1.0)
    assert off[0] == 0.0 and off[99] == 0.0


def test_field_does_not_nudge_when_the_lane_leaves_no_room():
    s = np.arange(0.0, 100.0, 1.0)
    off = nudge_offsets_m(s, [_static(50.0, 0.0, width=1.5)], 1.0, 1.75, -1.75, PotentialFieldConfig())
    assert np.all(off == 0.0)


def test_pullover_path_ends_at_the_spot_offset_and_merge_returns_to_the_lane():
    planner = LocalPathPlanner(ROUTE, half_width_m=1.0)
    spot = SE2(60.0, -3.6, 0.0)
    traj = planner.plan(Stamp(0), 30.0, 0.0, _decision(BehaviourState.PULLOVER, spot=spot), [])
    pts = traj.points
    assert abs(pts[0, 1]) < 1e-9
    beyond = pts[pts[:, 0] > 60.0]
    assert np.allclose(beyond[:, 1], -3.6, atol=1e-6)
    merge = planner.plan(
        Stamp(0), 60.0, -3.6, _decision(BehaviourState.MERGING, spot=spot, merge_from=60.0), []
    )
    far = merge.points[merge.points[:, 0] > 80.0]
    assert np.allclose(far[:, 1], 0.0, atol=1e-6)


def test_bezier_chain_equals_one_cubic_per_segment_exactly():
    pts = np.random.default_rng(3).normal(size=(12, 2)) * 20.0
    padded = np.vstack([2 * pts[0] - pts[1], pts, 2 * pts[-1] - pts[-2]])
    pieces = []
    for i in range(1, len(padded) - 2):
        p0, p3 = padded[i], padded[i + 1]
        p1 = p0 + (padded[i + 1] - padded[i - 1]) / 6.0
        p2 = p3 - (padded[i + 2] - padded[i]) / 6.0
        seg = cubic_bezier(p0, p1, p2, p3, 9)
        pieces.append(seg if i == len(padded) - 3 else seg[:-1])
    assert np.array_equal(smooth_through(pts), np.vstack(pieces))


def test_the_curb_floor_is_rounded_where_a_taper_meets_its_platform_and_never_lowered():
    # A 1:2.5 taper from the lane edge down to a bay's platform: with a plain maximum the front's
    # pull-over curve turned 0.38 rad at the corner (0.12-0.14 /m in snow seed 2's bay, where the
    # front-steered shuttle swung its front corner onto the platform's curb).
    step = 0.25
    s = np.arange(0.0, 60.0, step)
    floor = np.interp(s, [20.0, 28.75], [-0.67, -4.17])
    floor[s < 5.0] = -np.inf  # an opening: no curb
    rounded = rounded_floor_m(floor, step, 10.0)
    assert np.all(rounded >= floor)
    straight = (
        ((s > 5.0 + 5.0) & (s < 20.0 - 5.0)) | ((s > 20.0 + 5.0) & (s < 28.75 - 5.0)) | (s > 28.75 + 5.0)
    )
    assert rounded[straight] == pytest.approx(floor[straight])
    # Where the taper flattens onto the platform the 0.4 slope change is spread over the 10 m window
    # (the taper's start, a concave corner, is left as it is: rounding it would lower the floor).
    near = (s > 24.5) & (s < 40.0)
    slope = np.diff(rounded[near]) / step
    assert np.abs(np.diff(slope) / step).max() <= 0.4 / 10.0 + 1e-9
    corner = int(28.75 / step)
    assert rounded[corner] == pytest.approx(floor[corner] + 0.4 * 10.0 / 8.0, abs=0.02)  # lifted, by 0.5 m
    assert np.all(np.isneginf(rounded[s < 5.0 - 5.0]))
    assert rounded_floor_m(floor, step, 0.0) is floor
