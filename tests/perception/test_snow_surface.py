"""Curb-side surface is told from objects: a curb face (low, on a curb line), snow along a curb (low,
flat, bright, beside one)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.errors import ConfigError, MessageError
from lastmile.perception.cluster_geometry import CLUSTER_COLUMNS, describe_clusters
from lastmile.perception.pipeline import LidarPipeline
from lastmile.perception.snow_surface import (
    SnowSurfaceConfig,
    curb_distance_m,
    drop_clusters,
    snow_surface_clusters,
)
from tests.perception.synthetic import Box, Scene, default_rig, sweep

LEFT_CURB = np.array([[60.0, 3.5], [-30.0, 3.5]])  # across the road, road on its left (walked backwards)
RIGHT_CURB = np.array([[-30.0, -3.5], [60.0, -3.5]])


def _clusters(rows: list[tuple[float, float, float, float, float]]):
    """Clusters of 12 points each: (x, y, z_low, z_high, intensity) per cluster."""
    rng = np.random.default_rng(0)
    xyz, inten, lab = [], [], []
    for k, (x, y, z0, z1, i) in enumerate(rows):
        n = 12
        xyz.append(
            np.c_[x + rng.uniform(-0.3, 0.3, n), y + rng.uniform(-0.1, 0.1, n), np.linspace(z0, z1, n)]
        )
        inten.append(np.full(n, i))
        lab.append(np.full(n, k))
    return describe_clusters(np.vstack(xyz), np.concatenate(inten), np.concatenate(lab))


def test_low_flat_bright_cluster_on_a_curb_line_is_snow_and_objects_are_not():
    cl = _clusters(
        [
            (5.0, 3.2, 0.14, 0.17, 72.0),  # snow on the lane edge, 0.3 m from the left curb
            (5.0, 0.0, 0.14, 0.17, 72.0),  # the same, 3.5 m from any curb: not snow lying at a curb
            (8.0, 2.9, 0.02, 0.40, 45.0),  # a goose at the curb: 0.4 m tall
            (12.0, 3.0, 0.10, 1.70, 60.0),  # a pedestrian stepping off the kerb
            (9.0, 3.3, 0.00, 0.16, 30.0),  # the curb face and sidewalk edge: low, dim, on the line
            (14.0, -2.5, 0.10, 0.20, 35.0),  # low, flat and dim 1.0 m off the right curb: an object
            (16.0, -2.5, 0.10, 0.20, 70.0),  # ...and bright there: snow reaching 1.0 m into the lane
        ]
    )
    snow = snow_surface_clusters(cl, [LEFT_CURB, RIGHT_CURB])
    assert snow.tolist() == [True, False, False, False, True, False, True]
    assert not snow_surface_clusters(cl, []).any()  # no map curbs: nothing is called snow
    kept = drop_clusters(cl, snow)
    assert len(kept) == 4 and kept.table.shape[1] == len(CLUSTER_COLUMNS)
    assert kept.labels.tolist() == cl.labels[[1, 2, 3, 5]].tolist()
    assert kept.hull_xy.shape[0] == kept.hull_new.shape[0] == 4


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-20, 20), st.floats(-20, 20)), min_size=2, max_size=6, unique=True),
    st.lists(st.tuples(st.floats(-25, 25), st.floats(-25, 25)), min_size=1, max_size=10),
)
def test_curb_distance_matches_the_exact_distance_to_the_polyline_within_half_a_sample(line, pts):
    P = np.array(line, dtype=np.float64)
    if np.any(np.hypot(*np.diff(P, axis=0).T) < 1e-6):
        return
    q = np.array(pts, dtype=np.float64)
    step = 0.1
    got = curb_distance_m([P], q, step)
    a, b = P[:-1], P[1:]
    ab = b - a
    t = np.clip(np.einsum("qsk,sk->qs", q[:, None, :] - a, ab) / np.einsum("sk,sk->s", ab, ab), 0.0, 1.0)
    exact = np.hypot(*(a + t[..., None] * ab - q[:, None, :]).transpose(2, 0, 1)).min(axis=1)
    assert np.all(got >= exact - 1e-9)
    assert np.all(got <= exact + step / 2 + 1e-9)


def test_config_and_inputs_are_checked():
    with pytest.raises(ConfigError, match="min_mean_intensity"):
        SnowSurfaceConfig(min_mean_intensity=300.0)
    with pytest.raises(ConfigError, match="max_top_m"):
        SnowSurfaceConfig(max_top_m=-0.1)
    with pytest.raises(MessageError, match=r"curb_lines_xy_m\[0\]"):
        curb_distance_m([np.array([1.0, 2.0])], np.zeros((1, 2)), 0.1)
    assert math.isinf(float(curb_distance_m([], np.zeros((1, 2)), 0.1)[0]))


def _snowy_left_curb_frame():
    """A parked bus; ploughed snow 0.22 m deep covers 0.5 m of the lane along the left curb and
    slopes to the road over 0.6 m (the simulator's bank shape; deep enough to stand out of the
    ground tolerance here, as the simulator's bank does in the quality benchmark); a goose stands
    on the snow cover. Snow returns are bright (reflectivity 0.8), everything else dim."""
    scene = Scene(
        profile_y=(-5.0, -3.5, -3.49, 2.4, 3.0, 3.5, 5.0),
        profile_z=(0.15, 0.15, 0.0, 0.0, 0.22, 0.22, 0.22),
        boxes=(Box((8.0, 2.9, 0.0), (8.6, 3.2, 0.62), label=4),),
    )
    rng = np.random.default_rng(3)
    sweeps, boxes = [], []
    for lidar in default_rig():
        sw, box = sweep(scene, lidar, 0, rng)
        p = sw.points.astype(np.float64)
        B = lidar.base_from_sensor
        xyz = p[:, :3] @ B[:3, :3].T + B[:3, 3]
        on_snow = (box == -1) & (xyz[:, 1] > 2.4) & (xyz[:, 1] < 3.5) & (xyz[:, 2] > 0.02)
        p[on_snow, 3] = rng.uniform(62.0, 85.0, int(on_snow.sum()))
        sweeps.append(type(sw)(stamp=sw.stamp, sensor_id=sw.sensor_id, points=p.astype(np.float32)))
        boxes.append(box)
    ext = {lidar.sensor_id: lidar.base_from_sensor for lidar in default_rig()}
    return sweeps, ext, np.concatenate(boxes)


def test_pipeline_drops_snow_along_the_left_curb_given_the_map_curbs_and_keeps_the_goose():
    sweeps, ext, box = _snowy_left_curb_frame()
    pipe = LidarPipeline()
    old = pipe.process(sweeps, ext, None, None, RIGHT_CURB)  # the old call: no curb lines
    new = pipe.process(sweeps, ext, None, None, RIGHT_CURB, [LEFT_CURB, RIGHT_CURB])

    def on_snow(res):
        x, y = res.clusters.col("x_m"), res.clusters.col("y_m")
        top = res.clusters.col("z_max_m")
        return (np.abs(x) < 25) & (y > 2.3) & (y < 3.6) & (top < 0.3)

    assert on_snow(old).sum() >= 2  # without the map's curbs the snow cover clusters as objects
    assert on_snow(new).sum() == 0
    assert new.snow_surface.any() and not old.snow_surface.any()
    assert not (new.snow_surface & (box[new.source_index] == 0)).any()  # no goose point taken
    # The goose on the snow stays an object in both.
    for res in (old, new):
        x, y = res.clusters.col("x_m"), res.clusters.col("y_m")
        assert np.any((np.abs(x - 8.3) < 0.6) & (np.abs(y - 3.05) < 0.5))
    # Besides the snow, only the curb faces go: low clusters on a mapped curb line.
    gone = ~np.isin(old.clusters.labels, new.clusters.labels)
    assert gone[on_snow(old)].all()
    face = gone & ~on_snow(old)
    xy = np.c_[old.clusters.col("x_m"), old.clusters.col("y_m")][face]
    assert (old.clusters.col("z_max_m")[face] <= 0.3).all()
    assert (curb_distance_m([LEFT_CURB, RIGHT_CURB], xy, 0.1) <= 0.9).all()
