"""The grid Euclidean clustering gives exactly DBSCAN(min_samples=1)'s partition."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.cluster import DBSCAN

from lastmile.core.errors import MessageError
from lastmile.perception.clustering import canonical_labels, euclidean_cluster_labels


def _sklearn(xyz: np.ndarray, eps: float) -> np.ndarray:
    # kd_tree: the same float64 squared-distance test as ours, also on exact ties (brute force uses
    # the |a|^2 - 2ab + |b|^2 expansion, whose rounding can flip a pair at exactly eps).
    return DBSCAN(eps=eps, min_samples=1, algorithm="kd_tree").fit(xyz).labels_


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 600),
    eps=st.floats(0.05, 2.0),
    extent=st.floats(0.5, 30.0),
    flat=st.booleans(),
)
def test_partition_equals_sklearn_dbscan_min_samples_1_on_random_clouds(seed, n, eps, extent, flat):
    rng = np.random.default_rng(seed)
    # Blobs plus uniform clutter: both dense merges and chains of sparse links occur.
    centres = rng.uniform(-extent, extent, (max(1, n // 50), 3))
    pts = centres[rng.integers(0, len(centres), n)] + rng.normal(0, eps, (n, 3))
    pts[: n // 3] = rng.uniform(-extent, extent, (n // 3, 3))
    if flat:
        pts[:, 2] = 0.0  # a ground-like layer: many cells share one z
    ours = euclidean_cluster_labels(pts, eps)
    assert np.array_equal(ours, _sklearn(pts, eps))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 300), eps=st.sampled_from([1.0, 2.0, 0.5]))
def test_links_at_exactly_eps_are_kept_like_dbscan_on_integer_grids(seed, n, eps):
    rng = np.random.default_rng(seed)
    pts = rng.integers(-6, 6, (n, 3)).astype(np.float64) * eps / 2.0
    assert np.array_equal(euclidean_cluster_labels(pts, eps), _sklearn(pts, eps))


def test_float32_lidar_like_cloud_matches_sklearn():
    rng = np.random.default_rng(7)
    pts = (rng.normal(0, 8, (5000, 3)) * np.array([1, 1, 0.1])).astype(np.float32)
    lab = euclidean_cluster_labels(pts, 0.4)
    assert np.array_equal(lab, _sklearn(pts.astype(np.float64), 0.4))
    assert lab.max() > 10  # a non-trivial partition


def test_chain_of_links_joins_far_ends_and_a_gap_splits():
    x = np.r_[np.arange(0, 5.01, 0.5), np.arange(5.6, 7.0, 0.5)]
    pts = np.c_[x, np.zeros_like(x), np.zeros_like(x)]
    lab = euclidean_cluster_labels(pts, 0.5)
    assert len(set(lab[:11])) == 1 and lab[0] != lab[-1]


def test_canonical_labels_number_clusters_by_first_point():
    assert canonical_labels([5, 5, 2, 9, 2]).tolist() == [0, 0, 1, 2, 1]


def test_empty_cloud_and_bad_input():
    assert euclidean_cluster_labels(np.zeros((0, 3)), 0.5).shape == (0,)
    with pytest.raises(MessageError, match="expected \\(N, 3\\)"):
        euclidean_cluster_labels(np.zeros((4, 2)), 0.5)
    with pytest.raises(MessageError, match="positive finite eps"):
        euclidean_cluster_labels(np.zeros((4, 3)), 0.0)
    with pytest.raises(MessageError, match="finite coordinates"):
        euclidean_cluster_labels(np.array([[0.0, 0.0, np.nan]]), 0.5)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 600), eps=st.sampled_from([0.3, 0.5, 1.0]))
def test_rows_of_a_cloud_cluster_as_the_gathered_points(seed, n, eps) -> None:
    from lastmile.perception.clustering import euclidean_cluster_rows

    rng = np.random.default_rng(seed)
    xyz = np.round(rng.uniform(-10, 10, (n, 3)) * rng.uniform(0.05, 1.0), 2)  # ties at eps
    rows = np.flatnonzero(rng.random(n) < 0.7)
    got = euclidean_cluster_rows(xyz, rows, eps)
    assert np.array_equal(got, euclidean_cluster_labels(xyz[rows], eps))
    if len(rows):
        xyz[rows[-1], 1] = np.nan
        with pytest.raises(MessageError, match="finite"):
            euclidean_cluster_rows(xyz, rows, eps)
