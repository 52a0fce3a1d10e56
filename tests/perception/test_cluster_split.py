"""A pedestrian clustered together with the wall beside it is carved out; cars and walls stay whole."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.perception.cluster_split import ClusterSplitConfig, split_pedestrians
from lastmile.perception.clustering import euclidean_cluster_labels
from lastmile.perception.ground import AdaptiveGridGroundSegmenter
from tests.perception.synthetic import Box, Scene, base_cloud, default_rig

ON = ClusterSplitConfig(enabled=True)


def _clusters(boxes: tuple[Box, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    scene = Scene(profile_y=(-30.0, 30.0), profile_z=(0.0, 0.0), boxes=boxes)
    xyz, _, box = base_cloud(scene, default_rig()[0], np.random.default_rng(4))
    near = np.hypot(xyz[:, 0], xyz[:, 1]) < 30.0
    xyz, box = xyz[near], box[near]
    ground = AdaptiveGridGroundSegmenter().segment(xyz)
    labels = np.full(len(xyz), -1, dtype=np.int64)
    ng = np.flatnonzero(~ground)
    labels[ng] = euclidean_cluster_labels(xyz[ng], 0.5)
    return xyz, box, ground, labels


WALL = Box((6.0, 3.0, 0.0), (16.0, 3.3, 2.5))  # a 10 m wall 3 m to the left


@pytest.mark.parametrize("gap_m", [0.3, 0.45])
def test_a_pedestrian_beside_a_wall_gets_a_cluster_of_its_own(gap_m: float) -> None:
    ped = Box((10.0, 3.0 - gap_m - 0.5, 0.0), (10.5, 3.0 - gap_m, 1.75))
    xyz, box, ground, labels = _clusters((WALL, ped))
    body = (box == 1) & (xyz[:, 2] > 0.2)
    wall = (box == 0) & ~ground
    assert body.sum() > 50
    # Before: the 0.5 m link joins them.
    assert len(np.unique(labels[body])) == 1 and np.isin(labels[wall], labels[body]).mean() > 0.9
    after = split_pedestrians(xyz, labels, ground, ON)
    k = np.bincount(after[body]).argmax()
    assert (after[body] == k).mean() >= 0.95  # the body is one cluster...
    assert (after == k)[wall].mean() <= 0.02  # ...without the wall


def test_a_car_and_a_wall_alone_are_not_split() -> None:
    car = Box((8.0, -3.0, 0.0), (12.5, -1.2, 1.5))
    xyz, _, ground, labels = _clusters((WALL, car))
    after = split_pedestrians(xyz, labels, ground, ON)
    assert np.array_equal(after, labels)


def test_config_is_validated() -> None:
    with pytest.raises(ConfigError, match="max_height_m"):
        ClusterSplitConfig(min_height_m=2.0, max_height_m=1.0)
    with pytest.raises(ConfigError, match="split_eps_m"):
        ClusterSplitConfig(split_eps_m=0.0)
