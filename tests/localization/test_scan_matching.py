"""Scan-to-map matching: recovers a perturbed pose, a consistent covariance, degenerate scenes flagged."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError, MessageError
from lastmile.localization.scan_matching import ScanMatchConfig, ScanToMapMatcher


def _plane_points(rng, n, origin, u, v, size_u, size_v):
    a = rng.uniform(0, size_u, n)[:, None]
    b = rng.uniform(0, size_v, n)[:, None]
    return np.asarray(origin) + a * np.asarray(u) + b * np.asarray(v)


def _campus_map(rng, corridor=False):
    """Ground, building facades and light poles (WATonoBus's landmarks), or only a straight corridor."""
    parts = [_plane_points(rng, 30_000, (-60, -60, 0), (1, 0, 0), (0, 1, 0), 120, 120)]
    parts.append(_plane_points(rng, 8_000, (-60, 8, 0), (1, 0, 0), (0, 0, 1), 120, 8))
    parts.append(_plane_points(rng, 8_000, (-60, -8, 0), (1, 0, 0), (0, 0, 1), 120, 8))
    if not corridor:
        parts.append(_plane_points(rng, 6_000, (20, -8, 0), (0, 1, 0), (0, 0, 1), 16, 8))  # a facade across
        for px, py in ((-30, 5), (-10, -5.5), (5, 6), (35, -5)):
            theta = rng.uniform(0, 2 * math.pi, 600)
            z = rng.uniform(0, 6, 600)
            parts.append(np.c_[px + 0.15 * np.cos(theta), py + 0.15 * np.sin(theta), z])
    return np.concatenate(parts)


def _pose(x, y, yaw, z=1.8):
    t = np.eye(4)
    t[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    t[:3, 3] = (x, y, z)
    return t


def _scan(rng, map_points, pose, n=20_000, noise_m=0.02):
    """Points of the map within 40 m of the sensor, in the sensor frame, with range noise."""
    local = (map_points - pose[:3, 3]) @ pose[:3, :3]
    near = local[np.linalg.norm(local[:, :2], axis=1) < 40.0]
    pick = near[rng.choice(near.shape[0], min(n, near.shape[0]), replace=False)]
    return pick + rng.normal(0.0, noise_m, pick.shape)


@pytest.fixture(scope="module")
def campus():
    rng = np.random.default_rng(4)
    pts = _campus_map(rng)
    return pts, ScanToMapMatcher(pts)


def test_a_half_metre_three_degree_error_is_recovered_to_centimetres(campus):
    pts, matcher = campus
    rng = np.random.default_rng(5)
    truth = _pose(3.0, 1.0, 0.3)
    match = matcher.match(_scan(rng, pts, truth), _pose(3.4, 0.7, 0.3 + math.radians(3.0)))
    assert match.converged and match.confident
    assert math.hypot(match.x_m - 3.0, match.y_m - 1.0) < 0.02
    assert abs(match.yaw_rad - 0.3) < math.radians(0.1)
    assert match.inlier_share > 0.9 and match.rmse_m < 0.05


def test_the_reported_covariance_is_consistent_over_repeated_scans(campus):
    pts, matcher = campus
    rng = np.random.default_rng(6)
    nees = []
    for _ in range(12):
        truth = _pose(rng.uniform(-20, 20), rng.uniform(-2, 2), rng.uniform(-0.5, 0.5))
        init = truth.copy()
        init[:2, 3] += rng.normal(0.0, 0.3, 2)
        match = matcher.match(_scan(rng, pts, truth, noise_m=0.03), init)
        err = np.array([match.x_m - truth[0, 3], match.y_m - truth[1, 3]])
        nees.append(float(err @ np.linalg.solve(match.covariance[:2, :2], err)))
    assert np.mean(np.array(nees) <= 5.991) >= 0.9, nees


def test_a_straight_corridor_is_flagged_as_unconstrained_along_the_road():
    rng = np.random.default_rng(7)
    pts = _campus_map(rng, corridor=True)
    matcher = ScanToMapMatcher(pts)
    truth = _pose(0.0, 0.0, 0.0)
    match = matcher.match(_scan(rng, pts, truth), _pose(0.5, 0.2, 0.02))
    assert not match.confident
    # The along-road axis (x) is the uncertain one; across the road stays centimetres.
    assert math.sqrt(match.covariance[0, 0]) > 10 * math.sqrt(match.covariance[1, 1])
    assert abs(match.y_m) < 0.05


def test_bad_input_is_refused(campus):
    _, matcher = campus
    with pytest.raises(MessageError, match=r"scan_points: expected an \(N, 3\) array"):
        matcher.match(np.zeros((10, 2)), np.eye(4))
    with pytest.raises(MessageError, match="predicted_map_from_sensor"):
        matcher.match(np.zeros((100, 3)), np.eye(3))
    with pytest.raises(ConfigError, match="max_correspondence_m"):
        ScanMatchConfig(max_correspondence_m=0.0)
