"""Decision never yields to an unclassified track off the road that is not heading onto it."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TrackedObjects
from lastmile.core.stamp import Stamp
from lastmile.decision.decision_config import DecisionConfig
from lastmile.decision.offroad_unknowns import on_road_surface, yieldable_tracks

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
