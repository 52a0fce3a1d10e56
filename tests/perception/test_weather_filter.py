"""DROR removes snowflakes and keeps the points of real objects."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.errors import ConfigError, MessageError
from lastmile.perception.ground import make_ground_segmenter
from lastmile.perception.weather_filter import DrorConfig, azimuth_step_from_times, dror_keep_mask
from tests.perception.synthetic import base_cloud, campus_scene, default_rig, sweep


def test_snowflakes_are_removed_and_object_points_kept():
    rng = np.random.default_rng(3)
    lidar = default_rig()[0]
    xyz, _, box = base_cloud(campus_scene(rng), lidar, rng, snowflakes=600)
    ng = ~make_ground_segmenter("adaptive_grid").segment(xyz)
    sensor = np.tile([lidar.x_m, lidar.y_m], (int(ng.sum()), 1))
    keep = dror_keep_mask(xyz[ng], DrorConfig(), sensor)
    flakes = box[ng] == -2
    objects = box[ng] >= 2  # cars, pedestrians, geese, poles, the sign (0, 1 are the buildings)
    assert flakes.sum() > 300
    assert (~keep[flakes]).mean() >= 0.9
    # DROR trims the sparse ends of ring segments, but no object is lost.
    assert keep[objects].mean() >= 0.9
    for b in np.unique(box[ng][objects]):
        mine = box[ng] == b
        if mine.sum() >= 20:
            assert keep[mine].mean() >= 0.5


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(4, 40),
    r=st.floats(1.0, 60.0).filter(lambda r: abs(r - 20.0) > 1e-6),  # not on the range limit
)
def test_a_tight_group_always_survives_and_a_lone_point_never_does(seed, n, r):
    rng = np.random.default_rng(seed)
    cfg = DrorConfig()
    ang = rng.uniform(-np.pi, np.pi)
    centre = np.array([r * np.cos(ang), r * np.sin(ang), 1.0])
    group = centre + rng.uniform(-0.02, 0.02, (n, 3))  # all within min_radius of each other
    lone = centre + np.array([0.0, 0.0, 5.0])  # nothing within any radius the filter can use
    keep = dror_keep_mask(np.vstack([group, lone]), cfg)
    assert keep[:n].all()
    assert keep[n] == (r > cfg.max_range_m)  # beyond max_range_m points are not tested


def test_radius_grows_with_range_so_sparse_far_objects_survive():
    # Five points 0.12 m apart: too sparse for the 0.1 m radius at 5 m, fine at 30 m where the
    # radius is 5 * 30 m * 0.2 deg = 0.52 m.
    offsets = np.c_[np.zeros(5), np.arange(5) * 0.12, np.zeros(5)]
    near = offsets + np.array([5.0, 0, 1])
    far = offsets + np.array([30.0, 0, 1])
    cfg = DrorConfig(max_range_m=100.0)
    assert not dror_keep_mask(near, cfg).any()
    assert dror_keep_mask(far, cfg).all()


def test_config_is_validated():
    with pytest.raises(ConfigError, match="min_neighbours"):
        DrorConfig(min_neighbours=0)


def test_scan_line_shortcut_gives_the_same_mask():
    rng = np.random.default_rng(8)
    lidar = default_rig()[0]
    sw, _ = sweep(campus_scene(rng), lidar, 0, rng, snowflakes=400)
    p = sw.points.astype(np.float64)
    key = p[:, 4].astype(np.int64)  # one sensor: the ring is the scan line
    full = dror_keep_mask(p[:, :3], DrorConfig())
    fast = dror_keep_mask(p[:, :3], DrorConfig(), scan_key=key)
    assert np.array_equal(full, fast) and (~full).sum() > 100


@pytest.mark.parametrize(("columns", "deg"), [(1800, 0.2), (900, 0.4), (3600, 0.1)])
def test_azimuth_step_is_read_from_the_column_firing_times(columns: int, deg: float) -> None:
    k = np.repeat(np.arange(columns), 3)  # three returns per column
    t = (k * 100_000) // columns  # integer microseconds, as the LiDAR stamps them
    assert azimuth_step_from_times(t) == pytest.approx(np.radians(deg), rel=0.01)
    assert azimuth_step_from_times(np.zeros(5)) == 0.0


def test_a_thin_object_seen_by_a_coarse_unit_survives_with_that_units_step() -> None:
    # A blind-spot unit (0.4 deg columns) sees a post 9.6 m away with one ring: five columns
    # 6.7 cm apart. With the 32-channel unit's 0.2 deg the radius (0.17 m) leaves the two end
    # points of the row two neighbours each, one short of the three DROR asks for.
    step = np.radians(0.4)
    az = step * np.arange(-2, 3)
    xyz = np.c_[9.6 * np.cos(az), 9.6 * np.sin(az), np.full(5, 0.9)]
    assert dror_keep_mask(xyz).tolist() == [False, True, True, True, False]
    assert dror_keep_mask(xyz, azimuth_step_rad=np.full(len(xyz), step)).all()
    # A lone flake near the same unit still goes.
    flake = np.vstack([xyz, [[2.0, 0.5, 0.8]]])
    assert not dror_keep_mask(flake, azimuth_step_rad=np.full(len(flake), step))[-1]
    with pytest.raises(MessageError, match="azimuth_step_rad"):
        dror_keep_mask(xyz, azimuth_step_rad=np.ones(2))


def _dror_whole_pool_tree(p: np.ndarray, cfg: DrorConfig) -> np.ndarray:
    """The plain definition: every tested point queried in one KD-tree of all points in reach."""
    from scipy.spatial import cKDTree

    rng = np.hypot(p[:, 0], p[:, 1])
    radius = np.maximum(cfg.min_radius_m, cfg.multiplier * rng * cfg.azimuth_step_rad)
    test = np.flatnonzero(rng <= cfg.max_range_m)
    keep = np.ones(len(p), dtype=bool)
    if len(test):
        r_max = float(radius[test].max())
        pool = np.flatnonzero(rng <= cfg.max_range_m + r_max)
        dist, _ = cKDTree(p[pool]).query(p[test], k=cfg.min_neighbours + 1, distance_upper_bound=r_max)
        keep[test] = dist[:, -1] <= radius[test]
    return keep


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 400),
    spread=st.floats(0.5, 30.0),
    k=st.integers(1, 4),
)
def test_the_grid_neighbour_count_gives_the_whole_pool_tree_answer(seed, n, spread, k) -> None:
    # Clumps (dense, mostly kept) and scattered points (sparse, mostly removed), some beyond max range.
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-spread, spread, (max(1, n // 20), 3))
    p = centres[rng.integers(0, len(centres), n)] + rng.normal(0, 0.1, (n, 3))
    p[: n // 3] = rng.uniform(-spread, spread, (n // 3, 3))
    cfg = DrorConfig(min_neighbours=k, max_range_m=0.7 * spread)
    expected = _dror_whole_pool_tree(p, cfg)
    assert np.array_equal(dror_keep_mask(p, cfg), expected)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 300), k=st.integers(1, 4))
def test_neighbours_at_exactly_the_radius_count_as_in_the_tree(seed, n, k) -> None:
    # Points on a 0.5 m lattice and a 0.5 m radius floor: many neighbours lie exactly at the radius
    # (and at r_max), where a different distance formula or comparison would change the mask.
    rng = np.random.default_rng(seed)
    p = rng.integers(-8, 9, (n, 3)) * 0.5
    cfg = DrorConfig(min_neighbours=k, min_radius_m=0.5, multiplier=1e-3, max_range_m=3.0)
    expected = _dror_whole_pool_tree(p, cfg)
    assert np.array_equal(dror_keep_mask(p, cfg), expected)


def _coarse_unit_row(azimuth_rad: float, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """A car's end 9 m from a blind-spot unit (rings 3.33 deg apart, 0.4 deg columns, 0.9 m up):
    ``columns`` columns of one vertical face, 6 rings each, and their (N, 2) ``sensor, ring``."""
    step = np.radians(0.4)
    elev = np.radians(np.linspace(-40.0, 10.0, 16))[6:12]  # the rings that meet a car at 9 m
    az = azimuth_rad + step * (np.arange(columns) - (columns - 1) / 2)
    A, R = np.meshgrid(az, np.arange(6, 12), indexing="ij")
    E = elev[R - 6]
    h = 9.0  # a vertical face: the same horizontal range on every ring
    xyz = np.c_[h * np.cos(A).ravel(), h * np.sin(A).ravel(), 0.9 + h * np.tan(E).ravel()]
    return xyz, np.c_[np.zeros(A.size, dtype=np.int64), R.ravel()]


@pytest.mark.parametrize("azimuth_rad", [0.3, np.pi - 0.002, -np.pi + 0.001])
def test_a_vertical_row_seen_by_a_coarse_unit_survives_with_its_rings_as_neighbours(azimuth_rad) -> None:
    # Two columns 6 cm apart, rings 0.5 m apart: inside the radius (0.31 m) each point has one
    # neighbour, the other column's point of its ring; the radius test removes the whole car end.
    # On the scan grid the ring above and below are its neighbours too. Behind the unit the
    # azimuth window wraps across +-pi.
    xyz, grid = _coarse_unit_row(azimuth_rad, 2)
    steps = np.full(len(xyz), np.radians(0.4))
    assert not dror_keep_mask(xyz, azimuth_step_rad=steps).any()
    keep = dror_keep_mask(xyz, azimuth_step_rad=steps, scan_grid=grid)
    assert keep.all()
    off = dror_keep_mask(xyz, DrorConfig(ring_reach=0), azimuth_step_rad=steps, scan_grid=grid)
    assert not off.any()


def test_scan_neighbours_at_another_range_do_not_keep_a_flake() -> None:
    # A flake 3 m out in front of the car end, on one of its rings and columns: its scan
    # neighbours are the car's returns 6 m farther; it has no neighbour at its own range.
    xyz, grid = _coarse_unit_row(0.3, 2)
    flake = np.array([[3.0 * np.cos(0.3), 3.0 * np.sin(0.3), 0.9 + 3.0 * np.tan(np.radians(-20.0))]])
    p = np.vstack([xyz, flake])
    g = np.vstack([grid, [[0, 6]]])
    keep = dror_keep_mask(p, azimuth_step_rad=np.full(len(p), np.radians(0.4)), scan_grid=g)
    assert keep[:-1].all() and not keep[-1]
    # Three returns at the flake's range just above and below it (outside its 0.1 m radius) are
    # its scan neighbours when they are this LiDAR's next rings, not when another LiDAR saw them.
    row = flake + np.array([[0.0, 0.0, -0.2], [0.0, 0.0, 0.2], [0.0, 0.02, 0.2]])  # the next column
    q = np.vstack([p, row])
    steps = np.full(len(q), np.radians(0.4))
    same = np.vstack([g, [[0, 5], [0, 7], [0, 7]]])
    other = np.vstack([g, [[1, 5], [1, 7], [1, 7]]])
    assert not dror_keep_mask(q, azimuth_step_rad=steps)[len(p) - 1]
    assert dror_keep_mask(q, azimuth_step_rad=steps, scan_grid=same)[len(p) - 1]
    assert not dror_keep_mask(q, azimuth_step_rad=steps, scan_grid=other)[len(p) - 1]
    with pytest.raises(MessageError, match="scan_grid"):
        dror_keep_mask(p, scan_grid=np.zeros((2, 2), dtype=np.int64))
    with pytest.raises(ConfigError, match="ring_reach"):
        DrorConfig(ring_reach=-1)


def test_the_scan_pattern_test_keeps_flakes_out_on_a_whole_rig() -> None:
    # Every unit of the rig in snow: the scan-pattern test keeps more object points and removes
    # (almost) as many flakes as the radius test alone.
    rng = np.random.default_rng(5)
    scene = campus_scene(rng)
    kept = {False: [], True: []}
    gone = {False: [], True: []}
    for i, lidar in enumerate(default_rig()):
        sw, box = sweep(scene, lidar, 0, rng, snowflakes=300)
        p = sw.points.astype(np.float64)
        B = lidar.base_from_sensor
        xyz = p[:, :3] @ B[:3, :3].T + B[:3, 3]
        ng = ~make_ground_segmenter("adaptive_grid").segment(xyz)
        sensor = np.tile([lidar.x_m, lidar.y_m], (int(ng.sum()), 1))
        steps = np.full(int(ng.sum()), np.radians(lidar.azimuth_res_deg))
        grid = np.c_[np.full(int(ng.sum()), i), p[ng, 4].astype(np.int64)]
        for use in (False, True):
            keep = dror_keep_mask(xyz[ng], DrorConfig(), sensor, None, steps, grid if use else None)
            kept[use].append(keep[box[ng] >= 2])
            gone[use].append(~keep[box[ng] == -2])
    k0, k1 = np.concatenate(kept[False]), np.concatenate(kept[True])
    g0, g1 = np.concatenate(gone[False]), np.concatenate(gone[True])
    assert k1.mean() >= k0.mean() and (k1 >= k0).all()  # only ever adds points back
    assert g1.mean() >= 0.9 and g0.mean() - g1.mean() <= 0.02


def test_rows_of_a_merged_cloud_get_the_mask_of_their_gathered_inputs() -> None:
    # dror_keep_rows gathers each point's LiDAR position, step, scan key and grid from its
    # sensor index in one compiled pass: the verdicts are dror_keep_mask's on those gathered
    # arrays, bit for bit (every unit of the rig in snow, mixed steps).
    from lastmile.perception.merge import merged_points
    from lastmile.perception.weather_filter import dror_keep_rows

    rng = np.random.default_rng(11)
    scene = campus_scene(rng)
    rig = default_rig()
    sweeps = [sweep(scene, lidar, 0, rng, snowflakes=300)[0] for lidar in rig]
    _, pts = merged_points(sweeps, {lidar.sensor_id: lidar.base_from_sensor for lidar in rig})
    xyz = pts[:, :3].astype(np.float64)
    rows = np.flatnonzero(~make_ground_segmenter("adaptive_grid").segment(xyz))
    unit_xy = np.array([[lidar.x_m, lidar.y_m] for lidar in rig])
    unit_step = np.radians([0.1, 0.4, 0.2])  # one below the floor: floored at 0.2 deg
    sensor = pts[rows, 5].astype(np.int64)
    ring = pts[rows, 4].astype(np.int64)
    expected = dror_keep_mask(
        xyz[rows], DrorConfig(), unit_xy[sensor], sensor * 1000 + ring, unit_step[sensor], np.c_[sensor, ring]
    )
    got = dror_keep_rows(xyz, pts, rows, unit_xy, unit_step, DrorConfig())
    assert (~expected).sum() > 100  # the flakes go
    assert np.array_equal(got, expected)
    with pytest.raises(MessageError, match="finite"):
        dror_keep_rows(xyz, pts, rows, unit_xy, np.array([np.nan, 0.1, 0.1]))
