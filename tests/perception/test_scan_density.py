"""Returns of a sparse LiDAR count for the surface they cover in the cluster size filter."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import MessageError
from lastmile.perception.cluster_geometry import describe_clusters
from lastmile.perception.scan_density import return_weights, ring_spacing_from_points
from tests.perception.synthetic import campus_scene, default_rig, sweep


def test_ring_spacing_is_read_from_a_sweep_of_each_unit() -> None:
    rng = np.random.default_rng(2)
    scene = campus_scene(rng)
    front, left, _ = default_rig()
    sw_front, _ = sweep(scene, front, 0, rng)
    sw_left, _ = sweep(scene, left, 0, rng)
    # VLP-32C: 0.333 deg between the rings around the horizon; the synthetic 16-ring unit: 90 deg / 15.
    assert np.degrees(ring_spacing_from_points(sw_front.points)) == pytest.approx(0.333, abs=0.01)
    assert np.degrees(ring_spacing_from_points(sw_left.points)) == pytest.approx(90.0 / 15.0, abs=0.05)
    assert ring_spacing_from_points(np.zeros((0, 6))) == 0.0


def test_weights_are_cells_relative_to_the_densest_unit() -> None:
    h = np.radians([0.2, 0.4, 0.4])
    v = np.radians([0.333, 3.333, 0.0])  # the third unit's spacing is unknown
    w = return_weights(h, v)
    assert w[0] == 1.0 and w[1] == pytest.approx(20.0, rel=0.01) and w[2] == 1.0
    assert return_weights([0.1], [0.0]).tolist() == [1.0]


def test_a_short_row_of_a_sparse_unit_passes_the_size_filter_a_lone_return_never_does() -> None:
    # A car end 6.2 m away seen by a blind-spot unit: one column, three rings 0.44 m apart. The
    # dense unit's rule asks ceil(200 / 6.2**2) = 6 points there.
    row = np.c_[np.full(3, -6.1), np.full(3, 0.9), [0.46, 0.90, 1.34]]
    lone = np.array([[-5.0, -4.0, 0.5]])
    xyz = np.vstack([row, lone])
    lab = np.array([0, 0, 0, 1])
    inten = np.full(4, 40.0)
    assert len(describe_clusters(xyz, inten, lab)) == 0
    kept = describe_clusters(xyz, inten, lab, point_weight=np.full(4, 20.0))
    assert kept.labels.tolist() == [0]  # the lone return stays below the 2-point floor
    same = describe_clusters(xyz, inten, lab, point_weight=np.ones(4))
    assert len(same) == 0
    with pytest.raises(MessageError, match="point_weight"):
        describe_clusters(xyz, inten, lab, point_weight=np.full(4, 0.5))
