"""A scan match as the EKF's measurement: only the directions the scene constrains are fused; poor
matches are not fused at all."""

import math

import numpy as np

from lastmile.core.stamp import Stamp
from lastmile.localization.pose_graph import RelativeEdge, optimise, relative
from lastmile.localization.scan_match_localization import (
    ScanMatchingSettings,
    ScanMatchMeasurement,
    measurement,
)
from lastmile.localization.scan_matching import ScanMatch


def _measurement(cov: np.ndarray) -> ScanMatchMeasurement:
    return ScanMatchMeasurement(
        stamp=Stamp(0),
        x_m=1.0,
        y_m=2.0,
        yaw_rad=0.1,
        covariance=cov,
        max_direction_std_m=0.1,
        max_yaw_std_rad=0.01,
    )


def test_a_corridor_match_corrects_across_the_corridor_only() -> None:
    # A corridor along the direction 30 degrees: the matcher opened its covariance along it (1 m^2).
    along = np.array([math.cos(math.radians(30)), math.sin(math.radians(30))])
    cov = np.diag([0.02**2, 0.02**2, 0.002**2])
    cov[:2, :2] += np.outer(along, along)
    lin = _measurement(cov).linearize(np.array([0.0, 0.0, 0.1]), np.eye(3))
    assert lin is not None
    innovation, h, r = lin
    assert h.shape == (2, 3)  # one horizontal direction and the heading
    across = np.array([-along[1], along[0]])
    assert abs(abs(h[0, :2] @ across) - 1.0) < 1e-9 and abs(h[0, :2] @ along) < 1e-9
    assert math.isclose(abs(innovation[0]), abs(across @ np.array([1.0, 2.0])))
    np.testing.assert_allclose(r, h @ cov @ h.T)


def test_a_fully_constrained_match_is_fused_in_x_y_and_yaw() -> None:
    cov = np.diag([0.02**2, 0.03**2, 0.002**2])
    lin = _measurement(cov).linearize(np.array([0.5, 2.5, 0.1 + 2 * math.pi]), np.eye(3))
    assert lin is not None
    innovation, h, r = lin
    assert h.shape == (3, 3)
    np.testing.assert_allclose(h.T @ h, np.eye(3), atol=1e-12)  # x, y (any orthonormal axes) and yaw
    assert abs(innovation[-1]) < 1e-9  # the heading wraps
    assert np.allclose(r, h @ cov @ h.T)


def test_an_uninformative_or_infinite_match_is_not_fused() -> None:
    assert _measurement(np.diag([1.0, 1.0, 1.0])).linearize(np.zeros(3), np.eye(3)) is None
    assert _measurement(np.diag([np.inf, 1.0, 1.0])).linearize(np.zeros(3), np.eye(3)) is None


def _match(**over: object) -> ScanMatch:
    values: dict[str, object] = dict(
        map_from_sensor=np.eye(4),
        x_m=0.0,
        y_m=0.0,
        yaw_rad=0.0,
        covariance=np.diag([1e-4, 1e-4, 1e-6]),
        pos_std_m=0.01,
        yaw_std_rad=0.001,
        inlier_share=0.9,
        rmse_m=0.02,
        iterations=3,
        converged=True,
        confident=True,
    )
    values.update(over)
    return ScanMatch(**values)  # type: ignore[arg-type]


def test_poor_matches_are_refused_before_the_filter() -> None:
    settings = ScanMatchingSettings(map="unused.pcd")
    assert measurement(_match(), Stamp(5), settings) is not None
    assert measurement(_match(converged=False), Stamp(5), settings) is None
    assert measurement(_match(inlier_share=0.3), Stamp(5), settings) is None
    assert measurement(_match(rmse_m=0.15), Stamp(5), settings) is None


def test_the_pose_graph_spreads_the_priors_over_registered_frames() -> None:
    # Five frames 2 m apart; the first recorded 10 cm off sideways, the others right. Registrations say
    # they are exactly 2 m apart: chaining them to the first would carry its error; the graph does not.
    truth = np.array([[2.0 * k, 0.0, 0.0] for k in range(5)])
    priors = truth.copy()
    priors[0, 1] += 0.10
    covs = np.array([np.diag([0.02**2, 0.02**2, 0.002**2])] * 5)
    edges = [
        RelativeEdge(i=k, j=k - 1, z=relative(truth[k], truth[k - 1]), covariance=np.diag([1e-6, 1e-6, 1e-8]))
        for k in range(1, 5)
    ]
    chained = priors[0] + np.array([[2.0 * k, 0.0, 0.0] for k in range(5)])
    solved = optimise(chained, priors, covs, edges)
    assert np.max(np.abs(solved[:, 1] - truth[:, 1])) < 0.03  # the mean of the priors: 2 cm
    assert np.max(np.abs(chained[:, 1] - truth[:, 1])) > 0.09
