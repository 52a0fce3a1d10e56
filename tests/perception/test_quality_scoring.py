"""The perception-quality benchmark's scoring rules on a hand-made scene."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.sim.lidar_scene import PointLabel
from tests.perception import quality_scoring as qs

# A car 10 m ahead turned 90 degrees, a pedestrian at (5, -3), a goose at (20, 4).
BOXES = np.array(
    [
        [10.0, 0.0, math.pi / 2, 4.5, 1.8],
        [5.0, -3.0, 0.0, 0.5, 0.5],
        [20.0, 4.0, 0.3, 0.5, 0.3],
    ]
)


def test_footprint_distance_is_zero_inside_and_euclidean_outside_a_turned_box() -> None:
    d = qs.footprint_distance_m([[10.0, 2.0], [10.0, 3.25], [11.9, 0.0], [12.9, 4.25]], BOXES[:1])
    # The turned car spans x 9.1..10.9, y -2.25..2.25.
    np.testing.assert_allclose(d[:, 0], [0.0, 1.0, 1.0, math.hypot(2.0, 2.0)], atol=1e-12)


def test_each_cluster_goes_to_the_nearest_footprint_within_the_margin_only() -> None:
    centres = np.array(
        [
            [10.2, 1.5],  # inside the car
            [5.6, -3.0],  # 0.35 m from the pedestrian's edge: within 0.5 m
            [5.0, -2.0],  # 0.75 m from the pedestrian: too far
            [20.0, 4.4],  # beside the goose
            [40.0, 0.0],  # nothing there
        ]
    )
    matched = qs.match_clusters(centres, BOXES, margin_m=0.5)
    assert matched.tolist() == [0, 1, -1, 2, -1]
    assert qs.match_clusters(centres, np.zeros((0, 5)), 0.5).tolist() == [-1] * 5
    # A per-object margin: a pedestrian walking 1.5 m/s is matched 0.15 m farther out.
    assert qs.match_clusters(centres, BOXES, np.array([0.5, 0.9, 0.5]))[2] == 1


def test_an_object_split_into_two_clusters_is_found_once_and_a_missed_one_is_not() -> None:
    matched = np.array([0, 0, -1, 2])
    assert qs.objects_found(matched, 3).tolist() == [True, False, True]


def test_false_objects_are_unmatched_clusters_made_mostly_of_phantom_returns() -> None:
    # Cluster 0: matched car; 1: snowflakes; 2: a pole; 3: half road, half curb (not a majority of
    # phantom points); 4: sidewalk lumps plus one echo.
    matched = np.array([0, -1, -1, -1, -1])
    point_cluster = np.array([0, 0, 0, 1, 1, 1, 2, 2, 3, 3, 3, 3, 4, 4, 4, -1, -1])
    label = np.array(
        [
            PointLabel.ROAD,  # a car cluster with ground in it is still the car
            PointLabel.ROAD,
            PointLabel.OBJECT,
            PointLabel.WEATHER_NOISE,
            PointLabel.WEATHER_NOISE,
            PointLabel.WEATHER_NOISE,
            PointLabel.POLE,
            PointLabel.POLE,
            PointLabel.ROAD,
            PointLabel.ROAD,
            PointLabel.CURB,
            PointLabel.CURB,
            PointLabel.SIDEWALK,
            PointLabel.SIDEWALK,
            PointLabel.WEATHER_NOISE,
            PointLabel.WEATHER_NOISE,  # not clustered: removed by the filter, never an object
            PointLabel.WEATHER_NOISE,
        ]
    )
    assert qs.false_clusters(matched, point_cluster, label).tolist() == [False, True, False, False, True]


@pytest.mark.parametrize(("min_returns", "expected"), [(1, [True, True, False]), (3, [True, False, False])])
def test_visibility_counts_the_returns_carrying_each_object_id(
    min_returns: int, expected: list[bool]
) -> None:
    point_object = np.array([-1, 7, 7, 7, 3, -1, 7])
    ids = np.array([7, 3, 11])
    assert qs.returns_per_object(point_object, ids).tolist() == [4, 1, 0]
    assert qs.visible_objects(point_object, ids, min_returns).tolist() == expected
    assert qs.returns_per_object(np.array([-1, -1]), ids).tolist() == [0, 0, 0]


def test_returns_near_the_ground_do_not_make_an_object_visible() -> None:
    # Object 7 stands on the road (z 0), object 3 on a 0.15 m sidewalk; id 9 is not a listed object.
    point_object = np.array([7, 7, 7, 3, 3, 9, -1])
    z = np.array([0.05, 0.12, 0.3, 0.2, 0.3, 1.0, 1.0])
    counts = qs.returns_above_ground(point_object, z, np.array([3, 7]), np.array([0.15, 0.0]), 0.1)
    assert counts.tolist() == [1, 2]
    assert qs.returns_above_ground(point_object, z, np.zeros(0, np.int64), np.zeros(0), 0.1).tolist() == []
