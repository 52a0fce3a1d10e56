"""Poles and facades from a cloud's clusters: the right objects, the axis not the surface, honest sigmas."""

import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.stamp import Stamp
from lastmile.localization.landmark_extraction import LandmarkExtractionConfig, extract_landmarks
from lastmile.localization.landmark_localization import FacadeDetections, MapLandmarks, PoleDetections

CFG = LandmarkExtractionConfig()


def _pole(cx, cy, radius=0.12, top=4.0, step_deg=CFG.azimuth_step_deg, rings=40):
    """The near half of a column as a LiDAR at the origin sees it (returns at its azimuth steps)."""
    noise = np.random.default_rng(7)
    rng = math.hypot(cx, cy)
    half = math.degrees(math.asin(radius / rng))
    az0 = math.atan2(cy, cx)
    pts = []
    # The columns fall at a random phase against the column's edges.
    for da in np.arange(-half + noise.uniform(0.0, step_deg), half, step_deg):
        a = az0 + math.radians(da)
        d = np.array([math.cos(a), math.sin(a)])
        # First hit of the ray with the circle.
        b = d @ np.array([cx, cy])
        r = b - math.sqrt(max(b * b - (cx * cx + cy * cy - radius * radius), 0.0))
        for z in np.linspace(0.3, top, rings):
            noisy = r + noise.normal(0.0, 0.02)
            pts.append((noisy * d[0], noisy * d[1], z))
    return np.array(pts)


def _wall(p0, p1, top=4.0, spacing=0.1):
    noise = np.random.default_rng(8)
    n = int(math.dist(p0, p1) / spacing)
    t = np.linspace(0.0, 1.0, n)[:, None]
    xy = np.asarray(p0) + t * (np.asarray(p1) - np.asarray(p0))
    pts = [
        np.column_stack([xy + noise.normal(0, 0.02, xy.shape), np.full(n, z)])
        for z in np.linspace(0.2, top, 15)
    ]
    return np.vstack(pts)


def _box(cx, cy, w, h):
    g = np.stack(np.meshgrid(np.linspace(-w / 2, w / 2, 6), np.linspace(0.1, h, 12)), -1).reshape(-1, 2)
    return np.column_stack([cx + g[:, 0] * 0, cy + g[:, 0], g[:, 1]])


def _scene(*clusters):
    xyz = np.vstack(clusters)
    labels = np.concatenate([np.full(len(c), k) for k, c in enumerate(clusters)])
    return xyz, labels


def test_a_pole_is_found_at_its_axis_not_its_surface_and_people_and_sign_posts_are_not_poles():
    pole = _pole(15.0, -6.0)
    person = _box(8.0, 2.0, 0.5, 1.75)
    # A sign: a thin post to 1.7 m with a 0.6 m plate on top (lower than a lighting column).
    sign = np.vstack([_box(10.0, -4.0, 0.08, 1.7), _box(10.0, -4.0, 0.6, 2.3)])
    xyz, labels = _scene(pole, person, sign)
    found = extract_landmarks(xyz, labels, CFG)
    assert found.pole_xy_m.shape == (1, 2)
    err = float(np.hypot(*(found.pole_xy_m[0] - (15.0, -6.0))))
    surface_err = float(np.hypot(*(pole[:, :2].mean(axis=0) - (15.0, -6.0))))
    assert surface_err > 0.06  # the mean of the returns is on the near side...
    assert err < 0.05 and err < 0.6 * surface_err, err  # ...the axis is recovered
    assert err < 2.0 * found.pole_std_m[0]
    assert found.facade_lines.shape == (0, 2)


def test_a_far_pole_is_reported_less_certain_than_a_near_one():
    xyz, labels = _scene(_pole(8.0, -5.0), _pole(30.0, -9.0))
    found = extract_landmarks(xyz, labels, CFG)
    near, far = np.argsort(np.hypot(*found.pole_xy_m.T))
    assert found.pole_std_m[far] > found.pole_std_m[near] >= CFG.map_accuracy_m


def test_a_facade_and_a_corner_give_their_lines_a_short_fence_does_not():
    # An L-shaped building: a wall 18 m to the left along x and one across at x = 40 m.
    walls = np.vstack([_wall((5.0, 18.0), (35.0, 18.0)), _wall((35.0, 18.0), (35.0, 30.0))])
    fence = _wall((5.0, -6.0), (8.0, -6.0), top=1.2)
    xyz, labels = _scene(walls, fence)
    found = extract_landmarks(xyz, labels, CFG)
    lines = sorted(map(tuple, found.facade_lines))
    assert len(lines) == 2
    (rho_a, alpha_a), (rho_b, alpha_b) = lines
    assert rho_a == pytest.approx(18.0, abs=0.05) and alpha_a == pytest.approx(math.pi / 2, abs=0.01)
    assert rho_b == pytest.approx(35.0, abs=0.05) and alpha_b == pytest.approx(0.0, abs=0.01)
    assert (found.facade_distance_std_m >= CFG.map_accuracy_m).all()
    assert (found.facade_angle_std_rad > 0).all()


def test_detections_feed_the_measurements_with_their_own_sigmas():
    xyz, labels = _scene(_pole(15.0, -6.0), _wall((5.0, 18.0), (35.0, 18.0)))
    found = extract_landmarks(xyz, labels, CFG)
    marks = MapLandmarks(
        poles=np.array([[15.0, -6.0], [55.0, -6.0]]), segments=np.array([[[0.0, 18.0], [40.0, 18.0]]])
    )
    poles = PoleDetections(
        stamp=Stamp(0), points_base=found.pole_xy_m, std_m=1.0, landmarks=marks, point_std_m=found.pole_std_m
    )
    facades = FacadeDetections(
        stamp=Stamp(0),
        lines_base=found.facade_lines,
        distance_std_m=1.0,
        angle_std_rad=1.0,
        landmarks=marks,
        line_std=np.column_stack([found.facade_distance_std_m, found.facade_angle_std_rad]),
    )
    cov = np.diag([0.2, 0.2, 0.01]) ** 2
    nu, _, r = poles.linearize(np.zeros(3), cov)
    assert np.abs(nu).max() < 0.05 and r[0, 0] == pytest.approx(found.pole_std_m[0] ** 2)
    nu, _, r = facades.linearize(np.zeros(3), cov)
    assert np.abs(nu).max() < 0.05 and r[0, 0] == pytest.approx(found.facade_distance_std_m[0] ** 2)


def test_bad_input_is_one_clear_error():
    with pytest.raises(MessageError, match=r"expected \(N, 3\) points"):
        extract_landmarks(np.zeros((4, 2)), np.zeros(4, dtype=int), CFG)
    with pytest.raises(MessageError, match="finite"):
        extract_landmarks(np.full((4, 3), np.nan), np.zeros(4, dtype=int), CFG)
    with pytest.raises(MessageError, match="point_std_m"):
        PoleDetections(
            stamp=Stamp(0),
            points_base=np.zeros((2, 2)),
            std_m=0.1,
            landmarks=MapLandmarks(poles=np.zeros((0, 2)), segments=np.zeros((0, 2, 2))),
            point_std_m=np.array([0.1]),
        )
    with pytest.raises(ConfigError, match="pole_min_height_m"):
        LandmarkExtractionConfig(pole_min_height_m=0.0)
