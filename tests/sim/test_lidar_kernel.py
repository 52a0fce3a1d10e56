"""The simulated LiDAR's compiled passes agree bit for bit with their NumPy formulation, and the
install-time warm-up compiles every one of them for the types a run brings."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.sim import lidar_kernel
from lastmile.sim.lidar import LidarSimulator
from lastmile.sim.lidar_rig import EgoTrack, default_lidar_rig
from lastmile.sim.lidar_scene import DynamicObjects, PointLabel, static_scene
from lastmile.sim.lidar_warmup import entry_kernels, warm_up
from lastmile.sim.lidar_weather import lidar_weather

GEOM = VehicleGeometry()


def _nearest_numpy(n_col, n_ch, tan_el, oz, col, k0, k1, r_in, z_hi, cos2d, prim):  # type: ignore[no-untyped-def]
    """The NumPy formulation the kernel replaced: expand the (pair, channel) cells, ``np.minimum.at``
    per ray, the last candidate equal to the minimum wins."""
    counts = np.maximum(k1 - k0, 0)
    pair = np.repeat(np.arange(len(col)), counts)
    k = np.repeat(k0, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    tk = tan_el[k]
    rin = r_in[pair]
    top = oz + tk * rin > z_hi[pair]
    with np.errstate(divide="ignore", invalid="ignore"):
        r_hit = np.where(top, (z_hi[pair] - oz) / np.where(tk == 0.0, -1e-12, tk), rin)
    flat = col[pair] * n_ch + k
    best = np.full(n_col * n_ch, np.inf)
    np.minimum.at(best, flat, r_hit)
    winner = np.full(n_col * n_ch, -1, dtype=np.int64)
    won = np.flatnonzero(r_hit == best[flat])
    winner[flat[won]] = won
    hit = winner >= 0
    prim_out = np.full(n_col * n_ch, -1, dtype=np.int64)
    cos_out = np.ones(n_col * n_ch)
    w = winner[hit]
    prim_out[hit] = prim[pair[w]]
    cos_el = 1.0 / np.sqrt(1.0 + tk[w] ** 2)
    cos_out[hit] = np.where(top[w], np.abs(tk[w]) * cos_el, cos2d[pair[w]] * cos_el)
    return best, prim_out, cos_out


def test_nearest_hits_match_the_numpy_formulation_bit_for_bit_ties_and_nan_included() -> None:
    rng = np.random.default_rng(3)
    n_col, n_ch, n_pairs = 40, 16, 300
    tan_el = np.tan(np.radians(np.sort(rng.uniform(-30.0, 15.0, n_ch))))
    tan_el[5] = 0.0  # a level beam: the top's division guard
    col = rng.integers(0, n_col, n_pairs)
    k0 = rng.integers(0, n_ch, n_pairs)
    k1 = np.minimum(k0 + rng.integers(0, 6, n_pairs), n_ch)
    # Coarse ranges and heights: many rays meet several prisms at the same distance (ties).
    r_in = rng.integers(1, 8, n_pairs).astype(float)
    z_hi = rng.choice([0.5, 1.0, 1.9, 3.0], n_pairs)
    z_hi[:3] = 1.9  # the sensor's own height: 0.0 / -t, a negative zero
    r_in[7] = np.nan
    cos2d = rng.uniform(0.0, 1.0, n_pairs)
    prim = rng.integers(0, 50, n_pairs)
    args = (n_col, n_ch, tan_el, 1.9, col, k0, k1, r_in, z_hi, cos2d, prim)
    with np.errstate(invalid="ignore"):
        want = _nearest_numpy(*args)
    got = lidar_kernel.nearest_hits(*args)
    for a, b in zip(got, want, strict=True):
        assert a.dtype == b.dtype
        assert a.tobytes() == b.tobytes()
    assert np.isnan(got[0]).any() and (got[1] >= 0).sum() > 100


@pytest.fixture(scope="module")
def campus_sim() -> LidarSimulator:
    return LidarSimulator(
        static_scene(load_campus_map()), default_lidar_rig(GEOM), lidar_weather("clear"), 0, GEOM
    )


def test_ground_ranges_match_the_numpy_ground_bit_for_bit(campus_sim: LidarSimulator) -> None:
    sim = campus_sim
    spec = sim.specs["left"]  # low on the side: road, curb and sidewalk within a few metres
    tan_el = sim._beams["left"][0]
    ego = EgoTrack.constant(0, 250.0, -2.6, 0.1, speed_mps=4.0)
    cols, _ = sim.columns(spec, 0, ego, 100_000)
    n_ch = len(tan_el)
    cand = np.arange(spec.n_columns * n_ch, dtype=np.int64)
    r, label = sim._ground(spec, cols, tan_el, cand, n_ch)
    r_np, label_np = sim._ground_arrays(spec, cols, tan_el, cand // n_ch, cand % n_ch)
    assert r.tobytes() == r_np.tobytes() and label.tobytes() == label_np.tobytes()
    assert (label == PointLabel.SIDEWALK).sum() > 100 and (label == PointLabel.ROAD).sum() > 100


def test_the_warm_up_and_the_preload_compile_every_kernel_for_the_types_a_run_brings(
    campus_sim: LidarSimulator,
) -> None:
    report = warm_up()
    assert report.not_compiled == () and report.kernels == len(entry_kernels()) == 9
    before = {name: len(fn.signatures) for name, fn in entry_kernels().items()}  # type: ignore[attr-defined]
    # The campus rig in clear air and in snow (the snow path's ground stays in NumPy), road users in
    # view: no new compilation.
    objects = DynamicObjects.empty().with_box(
        x_m=262.0, y_m=-1.75, yaw_rad=0.0, length_m=4.5, width_m=1.8, height_m=1.5, object_id=4, vx_mps=3.0
    )
    ego = EgoTrack.constant(0, 250.0, -1.75, 0.0, speed_mps=5.0)
    snow = LidarSimulator(campus_sim.scene, tuple(campus_sim.specs.values()), lidar_weather("snow"), 0, GEOM)
    for sim in (campus_sim, snow):
        for sensor_id in sim.specs:
            sim.sweep_with_truth(sensor_id, Stamp(0), ego, objects, 100_000)
    after = {name: len(fn.signatures) for name, fn in entry_kernels().items()}  # type: ignore[attr-defined]
    assert after == before
    # One signature each: the one a simulator loads when it is built (``lidar_kernel.preload``).
    assert set(after.values()) == {1}


def _box_pairs_numpy(cols, box, starts, stops, ids):  # type: ignore[no-untyped-def]
    """The NumPy slab test the box kernel replaced, over the same column ranges."""
    counts = np.maximum(stops - starts, 0)
    prim = np.repeat(ids, counts)
    col = np.repeat(starts, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    c, s = np.cos(box.yaw_rad), np.sin(box.yaw_rad)
    hl, hw = box.half_length_m, box.half_width_m
    t_s = cols.t_s[col]
    cx = box.centre[prim, 0] + box.velocity[prim, 0] * t_s
    cy = box.centre[prim, 1] + box.velocity[prim, 1] * t_s
    px, py = cols.origin[col, 0], cols.origin[col, 1]
    dx, dy = cols.direction[col, 0], cols.direction[col, 1]
    cp, sp = c[prim], s[prim]
    ox, oy = px - cx, py - cy
    lox, loy = cp * ox + sp * oy, -sp * ox + cp * oy
    ldx, ldy = cp * dx + sp * dy, -sp * dx + cp * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        tx1, tx2 = (-hl[prim] - lox) / ldx, (hl[prim] - lox) / ldx
        ty1, ty2 = (-hw[prim] - loy) / ldy, (hw[prim] - loy) / ldy
    in_x, in_y = np.abs(lox) <= hl[prim], np.abs(loy) <= hw[prim]
    tx_lo = np.where(ldx == 0.0, np.where(in_x, -np.inf, np.inf), np.minimum(tx1, tx2))
    tx_hi = np.where(ldx == 0.0, np.where(in_x, np.inf, -np.inf), np.maximum(tx1, tx2))
    ty_lo = np.where(ldy == 0.0, np.where(in_y, -np.inf, np.inf), np.minimum(ty1, ty2))
    ty_hi = np.where(ldy == 0.0, np.where(in_y, np.inf, -np.inf), np.maximum(ty1, ty2))
    r_in, r_out = np.maximum(tx_lo, ty_lo), np.minimum(tx_hi, ty_hi)
    ok = (r_out >= r_in) & (r_out > 0.0)
    cos2d = np.where(tx_lo > ty_lo, np.abs(ldx), np.abs(ldy))
    return prim[ok], col[ok], r_in[ok], r_out[ok], cos2d[ok]


def test_box_pairs_match_the_numpy_slab_test_bit_for_bit_parallel_rays_included(
    campus_sim: LidarSimulator,
) -> None:
    from lastmile.sim.lidar_raycast import box_pairs, column_ranges

    sim = campus_sim
    spec = sim.specs["front"]
    ego = EgoTrack.constant(0, 250.0, -1.75, 0.0, speed_mps=5.0)
    cols, _ = sim.columns(spec, 0, ego, 100_000)
    objects = DynamicObjects.empty()
    rng = np.random.default_rng(5)
    for k in range(12):
        # Axis-aligned boxes (yaw 0 or pi/2) meet rays parallel to a slab along the straight.
        objects = objects.with_box(
            x_m=250.0 + rng.uniform(-25.0, 25.0),
            y_m=rng.uniform(-8.0, 6.0),
            yaw_rad=float(rng.choice([0.0, np.pi / 2, rng.uniform(-3.0, 3.0)])),
            length_m=rng.uniform(0.5, 5.0),
            width_m=rng.uniform(0.5, 2.0),
            height_m=1.5,
            object_id=k,
            vx_mps=rng.uniform(-5.0, 5.0),
        )
    box = objects.boxes
    got = box_pairs(cols, box)
    want = _box_pairs_numpy(cols, box, *column_ranges(cols, *_box_corners(cols, box)))
    assert len(got[0]) > 1000
    for a, b in zip(got, want, strict=True):
        assert a.tobytes() == b.tobytes()


def _box_corners(cols, box):  # type: ignore[no-untyped-def]
    c, s = np.cos(box.yaw_rad), np.sin(box.yaw_rad)
    local = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    lx = local[None, :, 0] * box.half_length_m[:, None]
    ly = local[None, :, 1] * box.half_width_m[:, None]
    corners = np.stack([c[:, None] * lx - s[:, None] * ly, s[:, None] * lx + c[:, None] * ly], axis=-1)
    t0, t1 = cols.t_s[0], cols.t_s[-1]
    return (
        corners + (box.centre + box.velocity * t0)[:, None, :],
        corners + (box.centre + box.velocity * t1)[:, None, :],
    )
