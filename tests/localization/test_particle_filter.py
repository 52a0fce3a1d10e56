"""NUS AMCL on a 2D occupancy map: tracking along a loop, KLD particle counts, recovery when lost."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError, MessageError
from lastmile.localization.particle_filter import AmclConfig, AmclLocalizer, OccupancyGrid

RES = 0.1


def _campus_grid() -> OccupancyGrid:
    """A 60 x 40 m block: outer walls, two buildings and a row of poles along the loop."""
    occ = np.zeros((400, 600), dtype=bool)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = True
    occ[120:280, 100:250] = True  # building A
    occ[150:260, 350:480] = True  # building B
    for x in range(60, 560, 70):
        occ[60:63, x : x + 3] = True  # poles along the south side of the loop
    return OccupancyGrid(occupied=occ, resolution_m=RES)


def _cast(grid: OccupancyGrid, pose, angles, max_range=30.0):
    """Ranges by stepping along each beam at a quarter cell."""
    steps = np.arange(0.0, max_range, RES / 4)
    xs = pose[0] + np.cos(pose[2] + angles)[:, None] * steps
    ys = pose[1] + np.sin(pose[2] + angles)[:, None] * steps
    col = np.clip((xs / RES).astype(int), 0, grid.occupied.shape[1] - 1)
    row = np.clip((ys / RES).astype(int), 0, grid.occupied.shape[0] - 1)
    hit = grid.occupied[row, col]
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), -1)
    return np.where(first >= 0, steps[np.maximum(first, 0)], np.inf)


def _loop(t):
    """A rectangle loop around building A at 2 m/s: (x, y, yaw)."""
    corners = [(5.0, 8.0), (30.0, 8.0), (30.0, 31.0), (5.0, 31.0)]
    lengths = [25.0, 23.0, 25.0, 23.0]
    d = (2.0 * t) % sum(lengths)
    for k, length in enumerate(lengths):
        if d <= length:
            a, b = np.array(corners[k]), np.array(corners[(k + 1) % 4])
            xy = a + (b - a) * d / length
            return xy[0], xy[1], math.atan2(*(b - a)[::-1])
        d -= length
    raise AssertionError


def _run(localizer, grid, rng, seconds=50.0, kidnap_at=None):
    angles = np.linspace(-math.pi, math.pi, 180, endpoint=False)
    errors, prev = [], _loop(0.0)
    for k in range(1, int(seconds * 10)):
        t = k * 0.1
        true = _loop(t)
        if kidnap_at is not None and t >= kidnap_at:
            true = (true[0] + 0.0, true[1], true[2])
        c, s = math.cos(prev[2]), math.sin(prev[2])
        dx, dy = true[0] - prev[0], true[1] - prev[1]
        delta = (c * dx + s * dy, -s * dx + c * dy, math.remainder(true[2] - prev[2], 2 * math.pi))
        noisy = (delta[0] * (1 + rng.normal(0, 0.02)), delta[1], delta[2] + rng.normal(0, 0.002))
        localizer.motion(noisy)
        ranges = _cast(grid, true, angles) + rng.normal(0.0, 0.03, angles.size)
        localizer.scan(ranges, angles)
        est = localizer.estimate()
        errors.append((t, math.hypot(est.x_m - true[0], est.y_m - true[1]), est))
        prev = true
    return errors


@pytest.fixture(scope="module")
def grid():
    return _campus_grid()


def test_amcl_tracks_a_loop_to_decimetres_and_shrinks_its_particle_set(grid):
    rng = np.random.default_rng(0)
    amcl = AmclLocalizer(grid, AmclConfig(), np.random.default_rng(1))
    start = _loop(0.0)
    amcl.initialise(start, (0.5, 0.5, 0.1))
    errors = _run(amcl, grid, rng, seconds=25.0)
    settled = np.array([e for t, e, _ in errors if t > 5.0])
    assert np.percentile(settled, 95) < 0.2
    final = errors[-1][2]
    assert final.confident and final.particles < AmclConfig().max_particles // 2  # KLD shrank the set
    assert final.random_injection < 0.05


def test_random_particles_are_injected_when_the_likelihood_collapses(grid):
    rng = np.random.default_rng(2)
    amcl = AmclLocalizer(grid, AmclConfig(), np.random.default_rng(3))
    amcl.initialise(_loop(0.0), (0.3, 0.3, 0.05))
    _run(amcl, grid, rng, seconds=10.0)
    assert amcl.random_injection < 0.05
    # Scans that match nothing near the particles (the vehicle was carried elsewhere): w_fast drops
    # below w_slow and random particles come in.
    angles = np.linspace(-math.pi, math.pi, 180, endpoint=False)
    for _ in range(10):
        amcl.motion((0.3, 0.0, 0.0))
        amcl.scan(_cast(grid, (55.0, 35.0, 2.0), angles), angles)
    assert amcl.random_injection > 0.1  # from < 0.05 while tracking


def test_bad_input_is_refused(grid):
    with pytest.raises(ConfigError, match="min_particles"):
        AmclConfig(min_particles=10, max_particles=5)
    amcl = AmclLocalizer(grid, None, np.random.default_rng(0))
    amcl.motion((1.0, 0.0, 0.0))
    with pytest.raises(MessageError, match="equal"):
        amcl.scan(np.ones(3), np.ones(4))
    with pytest.raises(MessageError, match="bool"):
        OccupancyGrid(occupied=np.zeros((3, 3)), resolution_m=0.1)
