"""Decision never yields to an unclassified track off the road that is not heading onto it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TrackedObjects
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.decision.decision_config import DecisionConfig
from lastmile.decision.offroad_unknowns import (
    kerbside_unknown_ids,
    on_road_surface,
    road_user_ids,
    unsettled_unknown_ids,
    yieldable_tracks,
)
from lastmile.decision.stop_constraints import in_path_constraints

# The straight test road: lane y in [-1.75, 1.75] along x 0..400, a crosswalk lanelet x 98..102 on
# it (the crosswalk's marking reaches y = 5.25 over the left sidewalk).


def _tracks(*rows: tuple[float, float, float, float, ObjectClass]) -> TrackedObjects:
    table = np.array([[x, y, vx, vy, 0.3, 0.1, 0.0, int(c), 0.1, 2.0] for x, y, vx, vy, c in rows])
    return TrackedObjects(stamp=Stamp(0), ids=np.arange(len(rows), dtype=np.int64), table=table)


def test_the_road_surface_is_the_lanes_and_the_crosswalk_lanelets(straight_map):
    on = on_road_surface(
        straight_map, np.array([[50.0, 0.0], [50.0, 2.0], [100.0, 1.0], [100.0, 4.0], [50.0, -1.7]])
    )
    assert on.tolist() == [True, False, True, False, True]


def test_an_unknown_object_beside_the_road_moving_along_it_is_not_yielded_to(straight_map):
    tracks = _tracks(
        (80.0, 2.2, 5.5, 0.0, ObjectClass.UNKNOWN),  # the phantom: beside the lane at the ego's speed
        (80.0, -2.3, 0.0, 0.0, ObjectClass.UNKNOWN),  # standing scenery on the right
        (80.0, 2.2, 0.0, -1.0, ObjectClass.UNKNOWN),  # heading onto the lane: kept
        (80.0, 2.2, 0.0, 0.0, ObjectClass.PEDESTRIAN),  # a pedestrian on the sidewalk: kept
        (80.0, 0.5, 0.0, 0.0, ObjectClass.UNKNOWN),  # on the lane: kept
        (100.0, 4.0, 0.0, 0.0, ObjectClass.UNKNOWN),  # on the marking over the sidewalk, standing
        (80.0, 1.78, 0.0, 0.0, ObjectClass.UNKNOWN),  # its box reaches over the lane edge: kept
    )
    kept = yieldable_tracks(tracks, straight_map, horizon_s=6.0)
    assert kept.ids.tolist() == [2, 3, 4, 6]


def test_an_unknown_object_reaching_the_road_only_after_the_horizon_is_not_yielded_to(straight_map):
    tracks = _tracks((80.0, 5.0, 0.0, -0.5, ObjectClass.UNKNOWN))  # on the lane after 6.5 s
    assert len(yieldable_tracks(tracks, straight_map, horizon_s=6.0)) == 0
    assert len(yieldable_tracks(tracks, straight_map, horizon_s=7.0)) == 1


def test_the_horizon_is_validated():
    with pytest.raises(ConfigError, match="offroad_unknown_horizon_s"):
        DecisionConfig(offroad_unknown_horizon_s=-1.0)


def test_a_standing_unknown_centred_beyond_the_road_edge_is_kerbside(straight_map):
    tracks = _tracks(
        (60.0, -1.78, 0.0, 0.0, ObjectClass.UNKNOWN),  # a blob on the lane's right edge, centre off it
        (60.0, -1.78, 0.5, 0.3, ObjectClass.UNKNOWN),  # its velocity estimate wandering: still standing
        (60.0, -1.78, 1.3, 0.0, ObjectClass.UNKNOWN),  # walking pace: not
        (60.0, -1.6, 0.0, 0.0, ObjectClass.UNKNOWN),  # centred on the lane: not
        (60.0, -1.78, 0.0, 0.0, ObjectClass.PEDESTRIAN),  # classified: not
    )
    assert kerbside_unknown_ids(tracks, straight_map, standing_mps=1.0) == frozenset({0, 1})


def test_at_the_kerb_a_standing_unknown_beyond_the_edge_is_judged_against_the_body():
    """Pulled over 0.6 m right of the route (the body's side at -1.6), a 0.1 m blob centred on the
    lane's edge at -2.02 is 0.37 m clear of the body: in the lane's 0.5 m corridor margin, it held the
    shuttle 60 s short of the Lanelet2 example's Roundabout West in snow; judged at the kerbside margin
    it is not in the path. Something the body would touch still is."""
    config = DecisionConfig()
    g = VehicleGeometry()
    path = Polyline(np.array([[0.0, -0.6], [200.0, -0.6]]))
    front = 50.0 + g.front_from_rear_axle_m

    def blob(d_m: float) -> RouteObstacle:
        s = front + 4.0
        return RouteObstacle(567, ObjectClass.UNKNOWN, s, d_m, s, 4.0, d_m, 0.0, 0.0, 0.1, 0.1)

    kerb = frozenset({567})
    assert in_path_constraints([blob(-2.02)], 0.0, path, g, config, front)  # the lane's margin
    assert in_path_constraints([blob(-2.02)], 0.0, path, g, config, front, kerb) == []
    assert in_path_constraints([blob(-1.70)], 0.0, path, g, config, front, kerb)  # within 0.1 m of the body


def test_the_kerbside_margin_is_validated():
    with pytest.raises(ConfigError, match="kerbside_margin_m"):
        DecisionConfig(kerbside_margin_m=0.6)
    with pytest.raises(ConfigError, match="kerbside_standing_mps"):
        DecisionConfig(kerbside_standing_mps=-1.0)


def test_unsettled_unknowns_are_the_young_unclassified_tracks_only():
    table = np.array(
        [
            [10.0, 0.0, 0.0, 0.0, 0.3, 0.1, 0.0, int(ObjectClass.UNKNOWN), 0.1, 0.4],
            [12.0, 0.0, 0.0, 0.0, 0.3, 0.1, 0.0, int(ObjectClass.UNKNOWN), 0.1, 1.0],
            [14.0, 0.0, 0.0, 0.0, 0.5, 0.5, 0.0, int(ObjectClass.PEDESTRIAN), 0.1, 0.0],
        ]
    )
    tracks = TrackedObjects(stamp=Stamp(0), ids=np.array([5, 6, 7], dtype=np.int64), table=table)
    assert unsettled_unknown_ids(tracks, 1.0) == frozenset({5})
    assert unsettled_unknown_ids(tracks, 0.0) == frozenset()


def test_unknown_settle_s_must_be_a_finite_non_negative_time():
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="unknown_settle_s"):
            DecisionConfig(unknown_settle_s=bad)


def test_a_new_unknown_beside_the_body_is_not_taken_for_a_lead():
    """Merging at 3 m/s, a 0.16 m track 0.3-0.6 s old keeping pace 0.75 m behind the front, 6 m/s
    along (a snow echo near the sensor, default service, snow, raw) was stopped for as a lead. A new
    unclassified track beside the body is not; a settled one there is, as before, and a new one ahead
    of the front is stopped for from birth."""
    config = DecisionConfig()
    g = VehicleGeometry()
    path = Polyline(np.array([[0.0, 0.0], [200.0, 0.0]]))
    front = 50.0 + g.front_from_rear_axle_m

    def echo(ds_m: float) -> RouteObstacle:
        s = front + ds_m
        return RouteObstacle(779, ObjectClass.UNKNOWN, s, 1.2, s, ds_m, 1.2, 6.2, 0.6, 0.16, 0.1)

    new = frozenset({779})
    assert in_path_constraints([echo(-0.75)], 3.0, path, g, config, front)  # settled: a lead
    assert in_path_constraints([echo(-0.75)], 3.0, path, g, config, front, unsettled_ids=new) == []
    assert in_path_constraints([echo(0.2)], 3.0, path, g, config, front, unsettled_ids=new)  # ahead
    # Standing beside the body, it is still judged as before (a swept turn may reach it).
    standing = dataclasses.replace(echo(-0.75), v_s_mps=0.0, v_d_mps=0.0)
    assert in_path_constraints([standing], 3.0, path, g, config, front, unsettled_ids=new)


def test_a_track_once_a_road_user_stays_one_while_tracked():
    def tracks(*rows: tuple[int, ObjectClass]) -> TrackedObjects:
        table = np.array([[0.0, 0.0, 0.0, 0.0, 0.5, 0.5, 0.0, int(c), 0.1, 0.5] for _, c in rows])
        return TrackedObjects(stamp=Stamp(0), ids=np.array([i for i, _ in rows], dtype=np.int64), table=table)

    seen = road_user_ids(tracks((1, ObjectClass.PEDESTRIAN), (2, ObjectClass.UNKNOWN)), frozenset())
    assert seen == frozenset({1})
    flickered = tracks((1, ObjectClass.UNKNOWN), (2, ObjectClass.UNKNOWN))
    seen = road_user_ids(flickered, seen)
    assert seen == frozenset({1})
    assert unsettled_unknown_ids(flickered, 1.0, seen) == frozenset({2})
    assert road_user_ids(tracks((2, ObjectClass.UNKNOWN)), seen) == frozenset()  # 1 ended: forgotten
