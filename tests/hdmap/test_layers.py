"""The s-layer database along the campus loop, and the drivable-area raster."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.hdmap import campus_layout as lay
from lastmile.hdmap.layers import ALL_WAY_STOP, BUS_BAY, CROSSWALK, DRIVEWAY, INTERSECTION, SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.model import DRIVABLE_SUBTYPES
from lastmile.hdmap.routing import campus_shuttle_loop


def _layers() -> SLayerDatabase:
    hdmap = load_campus_map()
    return SLayerDatabase.build(hdmap, campus_shuttle_loop(hdmap), step_m=1.0, closed=True)


def test_records_hold_lane_curb_speed_and_road_type() -> None:
    layers = _layers()
    assert np.allclose(np.diff(layers.s_m), 1.0)
    assert np.allclose(layers.lane_left_d_m, 1.75, atol=0.01)
    assert np.allclose(layers.lane_right_d_m, -1.75, atol=0.01)
    assert np.allclose(layers.speed_limit_mps, lay.ROAD_LIMIT_KMH / 3.6)
    for rs in layers.stops:
        mid = 0.5 * (rs.s_start_m + rs.s_end_m)
        assert abs(rs.s_end_m - rs.s_start_m - lay.BAY_PLATFORM_M) < 0.5
        assert abs(layers.curb_right_at(mid) - (-1.75 - lay.BAY_DEPTH_M)) < 0.01
        assert layers.road_type[layers.record_index(mid)] == BUS_BAY
    (line,) = [rl for rl in layers.stop_lines if rl.stop_line.signal_id is None]
    assert line.all_way_stop_id is not None
    x, y, _ = layers.centerline.point_at(line.s_m)
    assert math.hypot(x - (lay.T_X_M - lay.T_HALF_M), y + 1.75) < 0.01
    assert layers.road_type[layers.record_index(line.s_m + 5.0)] == INTERSECTION
    assert layers.intersection_type[layers.record_index(line.s_m + 5.0)] == ALL_WAY_STOP
    assert math.isnan(layers.curb_right_at(line.s_m + 5.0))  # the side road opens there
    assert len(layers.crosswalks) == 3
    for rc in layers.crosswalks:
        assert layers.road_type[layers.record_index(0.5 * (rc.s_start_m + rc.s_end_m))] == CROSSWALK
    park = layers.centerline.project(lay.PARK_X_M, lay.RING_H_M + 1.75).s_m
    assert layers.road_type[layers.record_index(park)] == DRIVEWAY


def test_landmarks_near_a_record_are_within_reach_and_nearest_first() -> None:
    layers = _layers()
    for s in (0.0, 500.0, 1200.0):
        x, y, _ = layers.centerline.point_at(s)
        near = layers.landmarks_near(s)
        assert near, f"no landmark near s={s}"
        dist = [math.hypot(*(np.asarray(lm.xy).mean(axis=0) - (x, y))) for lm in near]
        assert dist == sorted(dist) and max(dist) <= 40.0 + 1.0


@settings(max_examples=300, deadline=None)
@given(st.floats(-20.0, 780.0), st.floats(-160.0, 320.0))
def test_drivable_raster_agrees_with_the_exact_polygon_test(x: float, y: float) -> None:
    hdmap = load_campus_map()
    lid = hdmap.lanelet_at(x, y)
    exact = lid is not None and hdmap.lanelets[lid].subtype in DRIVABLE_SUBTYPES
    assert bool(hdmap.is_drivable(np.array([[x, y]]))[0]) == exact


def test_drivable_near_the_bay_curb() -> None:
    hdmap = load_campus_map()
    stop = hdmap.stops[0]
    x, y, h = stop.curb.point_at(stop.length_m / 2)
    nx, ny = -math.sin(h), math.cos(h)
    inside = hdmap.is_drivable(np.array([[x + 0.05 * nx, y + 0.05 * ny], [x - 0.05 * nx, y - 0.05 * ny]]))
    assert inside.tolist() == [True, False]
