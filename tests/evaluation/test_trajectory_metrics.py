"""Trajectory metrics: APE statistics agree with evo's ``evo_ape`` code; along/cross-track and NEES."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.errors import MessageError
from lastmile.evaluation.trajectory_metrics import (
    along_cross_track_m,
    ape_statistics,
    nees_2d,
    position_errors_m,
)


def _evo_ape(ref_xy: np.ndarray, est_xy: np.ndarray):
    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D
    from evo.main_ape import ape

    n = ref_xy.shape[0]
    t = np.arange(n) * 0.25
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))  # evo's order: w x y z
    ref = PoseTrajectory3D(np.c_[ref_xy, np.zeros(n)], quat, t)
    est = PoseTrajectory3D(np.c_[est_xy, np.zeros(n)], quat, t)
    return ape(ref, est, metrics.PoseRelation.translation_part).stats


@settings(max_examples=25, deadline=None)
@given(st.integers(5, 400), st.integers(0, 2**31 - 1), st.floats(0.01, 50.0))
def test_ape_statistics_agree_with_evo_to_a_micrometre(n, seed, scale):
    rng = np.random.default_rng(seed)
    ref = np.cumsum(rng.normal(0.0, 1.0, (n, 2)), axis=0) + rng.uniform(-1e4, 1e4, 2)
    est = ref + rng.normal(0.0, scale, (n, 2))
    ours = ape_statistics(position_errors_m(est, ref)).as_dict()
    theirs = _evo_ape(ref, est)
    for key in ("rmse", "mean", "median", "std", "min", "max"):
        assert ours[key] == pytest.approx(theirs[key], abs=1e-6), key
    assert ours["sse"] == pytest.approx(theirs["sse"], rel=1e-9)


def test_along_and_cross_track_follow_the_heading():
    err = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    lon, lat = along_cross_track_m(err, np.array([0.0, math.pi / 2, math.pi / 2]))
    assert lon == pytest.approx([1.0, 0.0, 2.0]) and lat == pytest.approx([0.0, -1.0, 0.0])


def test_nees_is_the_mahalanobis_square_and_is_chi_square_distributed():
    rng = np.random.default_rng(0)
    cov = np.array([[4.0, 1.0], [1.0, 1.0]])
    err = rng.multivariate_normal([0.0, 0.0], cov, 20_000)
    nees = nees_2d(err, np.broadcast_to(cov, (20_000, 2, 2)))
    assert nees.mean() == pytest.approx(2.0, rel=0.03)
    assert np.mean(nees <= 5.991) == pytest.approx(0.95, abs=0.005)


def test_bad_shapes_are_refused():
    with pytest.raises(MessageError, match=r"expected two \(N, 2\|3\) arrays"):
        position_errors_m(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(MessageError, match="non-empty finite"):
        ape_statistics(np.array([]))
