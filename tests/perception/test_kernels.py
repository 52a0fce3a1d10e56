"""The compiled (Numba) kernels give the array expressions' results bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.perception.cluster_geometry_kernel import box_extents, cloud_cluster_sums, hull_support
from lastmile.perception.deskew_kernel import bin_transforms, time_bins
from lastmile.perception.ground_kernel import plane_residuals, weighted_sums


def _clusters(seed: int, n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lab = np.sort(rng.integers(0, k, n))
    xy = rng.normal(0, 1, (n, 2)) * rng.uniform(0.1, 3, (k, 2))[lab] + rng.uniform(-30, 30, (k, 2))[lab]
    # Repeated coordinates: ties for the farthest point along a direction (the first must win).
    xy[::7] = np.round(xy[::7], 1)
    return xy, lab


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 400), k=st.integers(1, 12))
def test_support_points_are_the_first_points_farthest_along_each_direction(seed, n, k) -> None:
    xy, lab = _clusters(seed, n, k)
    _, starts, counts = np.unique(lab, return_index=True, return_counts=True)
    x, y = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])

    def directions(d: int) -> tuple[np.ndarray, np.ndarray]:
        ang = np.arange(d) * (2 * math.pi / d)
        return np.cos(ang), np.sin(ang)

    cos, sin = directions(32)
    hull, is_cand = hull_support(x, y, starts, counts, (directions(4), directions(8)), cos, sin)
    for row, (s0, c) in enumerate(zip(starts, counts, strict=True)):
        proj = x[s0 : s0 + c, None] * cos + y[s0 : s0 + c, None] * sin  # (c, 32)
        assert np.array_equal(hull[row], s0 + np.argmax(proj, axis=0))
        assert is_cand[hull[row]].all()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 300), k=st.integers(1, 8))
def test_cluster_sums_and_extents_equal_bincount_and_reductions(seed, n, k) -> None:
    xy, lab = _clusters(seed, n, k)
    p = np.c_[xy, np.random.default_rng(seed).normal(0, 1, n)]
    unit = np.random.default_rng(seed).integers(0, 3, n).astype(np.float32)
    weight = np.array([1.0, 2.5, 1.0 / 3.0])
    cloud_lab = np.where(np.arange(n) % 5 == 4, -1, lab)  # unlabelled points are skipped
    count, sx, sy, zmin, size = cloud_cluster_sums(p, cloud_lab, unit, weight, k)
    has = cloud_lab >= 0
    lab_h = cloud_lab[has]
    assert np.array_equal(count, np.bincount(lab_h, minlength=k))
    assert np.array_equal(sx, np.bincount(lab_h, weights=p[has, 0], minlength=k))
    assert np.array_equal(sy, np.bincount(lab_h, weights=p[has, 1], minlength=k))
    w = weight[unit[has].astype(np.int64)]
    assert np.array_equal(size, np.bincount(lab_h, weights=w, minlength=k))
    zref = np.full(k, np.inf)
    np.minimum.at(zref, lab_h, p[has, 2])
    assert np.array_equal(zmin, zref)
    _, starts, counts = np.unique(lab, return_index=True, return_counts=True)
    ang = np.random.default_rng(seed).uniform(0, math.pi, len(starts))
    ck, sk = np.cos(ang), np.sin(ang)
    x, y = np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1])
    row = np.repeat(np.arange(len(starts)), counts)
    pu = ck[row] * x + sk[row] * y
    pv = -sk[row] * x + ck[row] * y
    ref = np.stack(
        [
            np.minimum.reduceat(pu, starts),
            np.maximum.reduceat(pu, starts),
            np.minimum.reduceat(pv, starts),
            np.maximum.reduceat(pv, starts),
        ],
        axis=1,
    )
    assert np.array_equal(box_extents(x, y, starts, counts, ck, sk), ref)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000), n=st.integers(1, 500), regions=st.integers(1, 16), seed_pass=st.booleans()
)
def test_plane_fit_sums_equal_bincount_of_the_weighted_points(seed, n, regions, seed_pass) -> None:
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-20, 20, n), rng.uniform(-20, 20, n)
    z = rng.normal(0, 0.3, n)
    region = rng.integers(0, regions, n)
    planes = rng.normal(0, 0.05, (regions, 3))
    res = plane_residuals(x, y, z, region, planes)
    assert np.array_equal(
        res, z - (planes[:, 0][region] + planes[:, 1][region] * x + planes[:, 2][region] * y)
    )
    window = np.minimum(0.12 + 0.004 * np.hypot(x, y), 0.35)
    low = rng.normal(0, 0.1, regions)
    if seed_pass:
        sane = (res >= -1.0) & (res <= 1.0)
        rel = res - low[region]
        use = sane & (rel >= -0.15) & (rel <= 0.15)
        w = np.where(use, 1.0, 0.0)
    else:
        use = np.abs(res) <= window
        w = np.where(use, (1.0 - (res / window) ** 2) ** 2, 0.0)
    u = np.flatnonzero(use)
    xu, yu, zu, wu, ru = x[u], y[u], z[u], w[u], region[u]

    def s(v: np.ndarray) -> np.ndarray:
        return np.bincount(ru, weights=v, minlength=regions)

    wx, wy = wu * xu, wu * yu
    ref = np.stack(
        [s(wu), s(wx), s(wy), s(wu * zu), s(wx * xu), s(wx * yu), s(wy * yu), s(wx * zu), s(wy * zu)],
        axis=1,
    )
    ref = np.c_[ref, s((wu > 0).astype(np.float64))]
    got = weighted_sums(x, y, z, res, region, regions, seed_pass, low, window, 1.0, 1.0, 0.15)
    assert np.array_equal(got, ref)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 500), bin_us=st.integers(1, 2000))
def test_deskew_bins_and_transforms_equal_the_float32_array_expressions(seed, n, bin_us) -> None:
    rng = np.random.default_rng(seed)
    t_off = rng.uniform(-5_000, 100_000, n).astype(np.float32)
    stamp = int(rng.integers(0, 10**12))
    bins, t_lo, n_bins = time_bins(stamp, t_off, bin_us)
    t = stamp + t_off.astype(np.int64)
    assert t_lo == t.min() and np.array_equal(bins, (t - t.min()) // bin_us) and n_bins == bins.max() + 1
    p = rng.normal(0, 20, (n, 3)).astype(np.float32)
    Tc = rng.normal(0, 1, (12, n_bins)).astype(np.float32)
    out = bin_transforms(p, bins, Tc)
    for i in range(3):
        ref = Tc[4 * i][bins] * p[:, 0] + Tc[4 * i + 1][bins] * p[:, 1] + Tc[4 * i + 2][bins] * p[:, 2]
        assert np.array_equal(out[:, i], ref + Tc[4 * i + 3][bins])


def _key_window_counts(line, ring, az, rng_m, z, radius, query, reach, tan_s) -> np.ndarray:
    """The scan-pattern count as its definition on the keys: for each line around the query's and
    each of the three seam windows, the points whose key ``line * 10 + (az + pi)`` lies in
    ``[line * 10 + lo, line * 10 + hi]``, then the range and height tests."""
    key = line.astype(np.float64) * 10.0 + (az + math.pi)
    out = np.zeros(len(query), np.int64)
    for qi, me in enumerate(query):
        q_az, q_w = az[me] + math.pi, radius[me] / max(rng_m[me], 1e-9)
        tall = np.abs(ring - ring[me]) * rng_m[me] * tan_s + radius[me]
        near = (
            (np.arange(len(key)) != me)
            & (np.abs(rng_m - rng_m[me]) <= radius[me])
            & (np.abs(z - z[me]) <= tall)
        )
        for dr in range(-reach, reach + 1):
            base = float(line[me] + dr) * 10.0
            for s in range(3):
                shift = (s - 1) * 2 * math.pi
                lo = min(max(q_az - q_w + shift, 0.0), 2 * math.pi)
                hi = min(max(q_az + q_w + shift, 0.0), 2 * math.pi)
                if hi > lo:
                    out[qi] += np.count_nonzero(near & (key >= base + lo) & (key <= base + hi))
    return out


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(2, 300),
    reach=st.integers(1, 3),
    n_bins=st.sampled_from([1, 7, 720]),
)
def test_scan_window_counts_equal_the_scan_neighbour_definition(seed, n, reach, n_bins) -> None:
    from lastmile.perception.dror_kernel import scan_window_counts

    rng_ = np.random.default_rng(seed)
    ring = rng_.integers(0, 6, n)
    sensor = rng_.integers(0, 2, n)
    line = sensor * (6 + 2 * reach) + ring
    az = rng_.uniform(-math.pi, math.pi, n)
    az[::5] = np.round(az[::5], 1)  # shared azimuths: windows ending exactly on a point
    az[::11] = math.pi * rng_.choice([-1.0, 1.0])  # on the seam
    rng_m = rng_.uniform(0.5, 20, n)
    rng_m[::3] = np.round(rng_m[::3])
    rng_m[::13] = rng_.uniform(0.0, 0.05)  # at the sensor: windows wider than a turn
    z = rng_.normal(0, 1, n)
    radius = rng_.uniform(0.05, 1.0, n)
    width = radius / np.maximum(rng_m, 1e-9)
    query = np.flatnonzero(rng_.random(n) < 0.5)
    pool = np.arange(n)
    tan_s = math.tan(math.radians(3.4))
    got = scan_window_counts(pool, line, ring, az, rng_m, z, radius, query, reach, tan_s, n_bins)
    # Bit for bit the count on the keys, whatever the buckets.
    assert np.array_equal(got, _key_window_counts(line, ring, az, rng_m, z, radius, query, reach, tan_s))
    for qi, me in enumerate(query):
        d_az = np.abs((az - az[me] + math.pi) % (2 * math.pi) - math.pi)  # wrapped azimuth gap
        tall = np.abs(ring - ring[me]) * rng_m[me] * tan_s + radius[me]
        ok = (
            (np.abs(line - line[me]) <= reach)
            & (np.arange(n) != me)
            & (d_az <= width[me] * (1 + 1e-9))
            & (np.abs(rng_m - rng_m[me]) <= radius[me])
            & (np.abs(z - z[me]) <= tall)
        )
        if width[me] >= math.pi:
            continue  # a window wider than the turn: the seam windows overlap (counted twice)
        # Only where the gap is clearly inside or outside the window (the kernel's window edges
        # are float sums on the key; the pipeline's bit identity is checked on real frames).
        edge = np.abs(d_az - width[me]) < 1e-9
        assert got[qi] >= np.count_nonzero(ok & ~edge) and got[qi] <= np.count_nonzero(ok | edge)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 500), n_sec=st.sampled_from([8, 16, 32]))
def test_ground_ring_kernels_equal_their_array_expressions(seed, n, n_sec) -> None:
    from lastmile.perception.ground import AdaptiveGridConfig, _low_quantile
    from lastmile.perception.ground_kernel import classify_ring, low_quantile, ring_points

    cfg = AdaptiveGridConfig()
    rng_ = np.random.default_rng(seed)
    x, y = rng_.uniform(-40, 40, n), rng_.uniform(-40, 40, n)
    z = rng_.normal(0, 0.3, n)
    az = np.arctan2(y, x)
    az[::4] = np.round(az[::4], 1)  # sector boundaries hit exactly
    tol, road = rng_.uniform(0.1, 0.35, n), rng_.random(n) < 0.5
    idx = np.sort(rng_.choice(n, size=max(1, n // 2), replace=False))
    px, _, pz, window, region = ring_points(idx, x, y, z, az, tol, road, 2 * math.pi / n_sec, n_sec)
    sec = np.floor((az[idx] + math.pi) / (2 * math.pi / n_sec)).astype(int) % n_sec
    assert np.array_equal(region, sec * 2 + road[idx])
    assert np.array_equal(px, x[idx]) and np.array_equal(pz, z[idx]) and np.array_equal(window, tol[idx])
    res = rng_.normal(0, 0.3, len(idx))
    res[::3] = np.round(res[::3], 2)  # on histogram bin edges
    sane = (res >= -cfg.max_below_m) & (res <= cfg.seed_window_m)
    low = low_quantile(res, region, 2 * n_sec, cfg.max_below_m, cfg.seed_window_m, 0.05, cfg.seed_quantile)
    assert np.array_equal(low, _low_quantile(res[sane], region[sane], 2 * n_sec, cfg))
    ground = np.zeros(n, dtype=bool)
    below = classify_ring(
        idx, res, region, window, 2 * n_sec, cfg.smooth_floor_m, cfg.smooth_sigmas, ground, cfg.max_below_m
    )
    assert np.array_equal(below, np.bincount(region[res < -cfg.max_below_m], minlength=2 * n_sec))
    inlier = np.abs(res) <= window
    n_in = np.bincount(region[inlier], minlength=2 * n_sec)
    ss = np.bincount(region[inlier], weights=res[inlier] ** 2, minlength=2 * n_sec)
    smooth = np.maximum(cfg.smooth_floor_m, cfg.smooth_sigmas * np.sqrt(ss / np.maximum(n_in, 1)))
    expected = np.zeros(n, dtype=bool)
    expected[idx] = res <= np.minimum(window, smooth[region])
    assert np.array_equal(ground, expected)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 2000), bits=st.sampled_from([1, 8, 16, 17, 33, 62]))
def test_radix_argsort_is_a_stable_argsort(seed, n, bits) -> None:
    from lastmile.perception.clustering_kernel import radix_argsort

    key = np.random.default_rng(seed).integers(0, 2**bits, n, dtype=np.int64)
    assert np.array_equal(radix_argsort(key), np.argsort(key, kind="stable"))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n_sec=st.sampled_from([1, 8, 32]), lam=st.sampled_from([0.0, 4.0]))
def test_ground_plane_fit_equals_its_array_form(seed, n_sec, lam) -> None:
    from lastmile.perception.ground import AdaptiveGridConfig, _fit_planes, _fit_planes_array_form
    from lastmile.perception.ground_kernel import weighted_sums

    cfg = AdaptiveGridConfig(prior_weight=lam)
    g = np.random.default_rng(seed)
    n = int(g.integers(0, 400))
    x, y = g.uniform(-40, 40, n), g.uniform(-40, 40, n)
    # Planes of every kind: flat, steep (rejected), far from the prior (rejected), a step.
    z = g.normal(0, 0.05, n) + g.choice([0.0, 0.3, 2.0], n) + g.choice([0.0, 0.5], n) * x
    region = g.integers(0, 2 * n_sec, n)
    res = z - 0.0
    sums = weighted_sums(
        x, y, z, res, region, 2 * n_sec, True, np.zeros(2 * n_sec), np.full(n, 0.3), 1.0, 1.0, 0.15
    )
    sums[g.random(2 * n_sec) < 0.2] = 0.0  # empty regions: 0/0 centroids, singular without prior
    prior = g.normal(0, 0.1, (2 * n_sec, 3))
    with np.errstate(all="ignore"):
        try:
            want = _fit_planes_array_form(sums, prior.copy(), cfg)
        except np.linalg.LinAlgError:
            with pytest.raises(np.linalg.LinAlgError):
                _fit_planes(sums, prior.copy(), cfg)
            return
        got = _fit_planes(sums, prior.copy(), cfg)
    assert np.array_equal(got[0], want[0], equal_nan=True) and np.array_equal(got[1], want[1])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 3000))
def test_ground_ring_prelude_equals_its_array_expressions(seed, n) -> None:
    from lastmile.perception.ground import AdaptiveGridConfig
    from lastmile.perception.ground_kernel import ring_prelude

    cfg = AdaptiveGridConfig()
    g = np.random.default_rng(seed)
    x, y = g.uniform(-150, 150, n), g.uniform(-150, 150, n)
    if n:
        x[:: max(1, n // 7)] = np.asarray(cfg.ring_edges_m)[g.integers(0, len(cfg.ring_edges_m))]  # on edges
        y[:: max(1, n // 7)] = 0.0
    edges = np.asarray(cfg.ring_edges_m)
    tol, by_ring, ring_start = ring_prelude(
        x, y, edges, cfg.threshold_near_m, cfg.threshold_per_m, cfg.threshold_max_m, len(cfg.sectors_per_ring)
    )
    r = np.hypot(x, y)
    ring = np.searchsorted(edges, r, side="right") - 1
    order = np.argsort(ring, kind="stable")
    assert np.array_equal(tol, cfg.threshold_m(r))
    assert np.array_equal(by_ring, order)
    assert np.array_equal(ring_start, np.searchsorted(ring[order], np.arange(len(cfg.sectors_per_ring) + 1)))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 400), k=st.integers(1, 4), sparse=st.booleans())
def test_scan_line_sure_counts_each_lines_neighbours_in_the_given_order(seed, n, k, sparse) -> None:
    from lastmile.perception.dror_kernel import scan_line_sure

    rng_ = np.random.default_rng(seed)
    key = rng_.integers(0, 5, n) * (10**9 if sparse else 1)  # sparse keys: ranked, not offset
    x, y, z = (np.round(rng_.normal(0, 0.3, n), 2) for _ in range(3))  # ties on the radius
    radius = rng_.choice([0.1, 0.2, 0.5], n)
    # The definition: lines grouped stably, the pairs k apart at most within a line.
    order = np.argsort(key, kind="stable")
    count = np.zeros(n, np.int64)
    for off in range(1, k + 1):
        a, b = order[:-off], order[off:]
        same = key[a] == key[b]
        d2 = (x[b] - x[a]) ** 2 + (y[b] - y[a]) ** 2 + (z[b] - z[a]) ** 2
        r = np.minimum(radius[a], radius[b])
        hit = same & (d2 <= r * r)
        np.add.at(count, a[hit], 1)
        np.add.at(count, b[hit], 1)
    assert np.array_equal(scan_line_sure(x, y, z, key, radius, k), count >= k)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 400))
def test_merge_transform_and_crop_equal_their_float32_array_expressions(seed, n) -> None:
    from lastmile.perception.deskew_kernel import crop_points, rigid_transform_into

    rng_ = np.random.default_rng(seed)
    p = rng_.normal(0, 20, (n, 6)).astype(np.float32)
    B = rng_.normal(0, 1, (4, 4)).astype(np.float32)
    out = np.full((n + 3, 6), np.nan, np.float32)
    rigid_transform_into(p, B, out, 2, 7)
    for i in range(3):
        ref = p[:, 0] * B[i, 0] + p[:, 1] * B[i, 1] + p[:, 2] * B[i, 2] + B[i, 3]
        assert np.array_equal(out[2 : 2 + n, i], ref)
    assert np.array_equal(out[2 : 2 + n, 3:5], p[:, 3:5]) and (out[2 : 2 + n, 5] == 7).all()
    assert np.isnan(out[:2]).all() and np.isnan(out[2 + n :]).all()  # nothing else written
    # Bounds a float32 coordinate can equal while the float64 bound differs (1.2, 4.6), NaN too.
    bounds = dict(x_min=-1.2, x_max=4.6, half_width=1.2, z_max=1.2, ego_x_min=-0.3, ego_x_max=1.2, ego_w=0.3)
    pts = rng_.choice(np.array([-1.2, -0.3, 0.0, 0.3, 1.2, 4.6, 5.0, np.nan], np.float32), (n, 6))
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    roi = (x >= bounds["x_min"]) & (x <= bounds["x_max"]) & (np.abs(y) <= bounds["half_width"])
    roi &= z <= bounds["z_max"]
    ego = (x >= bounds["ego_x_min"]) & (x <= bounds["ego_x_max"]) & (np.abs(y) <= bounds["ego_w"])
    rows, kept, xyz = crop_points(
        pts,
        np.array([bounds[k] for k in ("x_min", "x_max", "half_width", "z_max")], np.float32),
        np.array([bounds[k] for k in ("ego_x_min", "ego_x_max", "ego_w")], np.float32),
    )
    assert np.array_equal(rows, np.flatnonzero(roi & ~ego))
    assert np.array_equal(kept, pts[rows], equal_nan=True)
    assert np.array_equal(xyz, pts[rows, :3].astype(np.float64), equal_nan=True)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 400), n_seg=st.sampled_from([1, 7, 360]))
def test_himmelsbach_fill_and_segment_members_equal_their_array_expressions(seed, n, n_seg) -> None:
    from lastmile.perception.himmelsbach import _fill_forward
    from lastmile.perception.himmelsbach_kernel import fill_forward, segment_members

    rng_ = np.random.default_rng(seed)
    ids = np.where(rng_.random((n_seg, 9)) < 0.6, -1, rng_.integers(0, 50, (n_seg, 9)))
    assert np.array_equal(fill_forward(ids), _fill_forward(ids))
    az = rng_.uniform(-math.pi, math.pi, n)
    az[::7] = rng_.choice([-math.pi, math.pi, 0.0])  # the seam and a segment edge
    points = np.sort(rng_.choice(n, size=max(1, n // 10), replace=False))
    segment = (np.floor((az + math.pi) / (2 * math.pi) * n_seg).astype(np.int64)) % n_seg
    need = np.zeros(n_seg, dtype=bool)
    need[segment[points]] = True
    assert np.array_equal(segment_members(az, points, n_seg), np.flatnonzero(need[segment]))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(0, 20_000),
    distinct=st.integers(1, 30_000),
    run=st.integers(1, 40),
)
def test_first_of_each_value_finds_np_uniques_first_indices(seed, n, distinct, run) -> None:
    # Runs of equal values (a column listed beam by beam) and more distinct values than the
    # starting table holds (it grows) alike.
    from lastmile.perception.dror_kernel import first_of_each_value

    rng_ = np.random.default_rng(seed)
    values = np.repeat(rng_.integers(0, distinct, n) * 0.25, run)[:n]
    values[::7] *= -1.0  # -0.0 and +0.0 are one value
    _, first = np.unique(values, return_index=True)
    got, finite = first_of_each_value(values)
    assert finite and np.array_equal(got, np.sort(first))
    if n:
        values[n // 2] = np.nan
        assert not first_of_each_value(values)[1]
