"""Shared fixtures: a small hand-made straight road with a bus bay and a crosswalk; Hypothesis profiles."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import settings

from lastmile.core.polyline import Polyline
from lastmile.hdmap.layers import RouteCrosswalk, RouteStop, SLayerDatabase
from lastmile.hdmap.model import BusStop, Crosswalk, HDMap, LaneletInfo

LANE_W = 3.5

# The suite is deterministic: property tests draw the same examples on every run, so CI and a
# developer see the same result. Searching for new counter-examples is a separate, explicit run:
# HYPOTHESIS_PROFILE=explore (fresh random draws on every run, and 1000 examples where a test does not
# set its own count; README "Tests"), whose finds become @example cases.
settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False, max_examples=1000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))


def _lanelet(lid: int, x0: float, x1: float, y_right: float, width: float, **kw: object) -> LaneletInfo:
    xs = np.array([x0, x1])
    return LaneletInfo(
        id=lid,
        centerline=Polyline(np.c_[xs, np.full(2, y_right + width / 2)]),
        left=Polyline(np.c_[xs, np.full(2, y_right + width)]),
        right=Polyline(np.c_[xs, np.full(2, y_right)]),
        speed_limit_mps=20 / 3.6,
        **kw,  # type: ignore[arg-type]
    )


@pytest.fixture(scope="session")
def straight_map() -> HDMap:
    """A 400 m eastbound lane (centre y = 0), bays at x 200-224 and 300-324, a crosswalk at x=100."""
    lanes = {
        1: _lanelet(1, 0.0, 400.0, -1.75, LANE_W),
        2: _lanelet(2, 200.0, 224.0, -4.75, 3.0, bus_stop_id="S1"),
        3: _lanelet(3, 98.0, 102.0, -1.75, LANE_W, subtype="crosswalk"),
        4: _lanelet(4, 300.0, 324.0, -4.75, 3.0, bus_stop_id="S2"),
    }
    stop = BusStop(
        id="S1",
        name="Test",
        lane_lanelet_id=1,
        bay_lanelet_id=2,
        curb=Polyline(np.array([[200.0, -4.75], [224.0, -4.75]])),
    )
    stop2 = BusStop(
        id="S2",
        name="Test 2",
        lane_lanelet_id=1,
        bay_lanelet_id=4,
        curb=Polyline(np.array([[300.0, -4.75], [324.0, -4.75]])),
    )
    cw = Crosswalk(
        id=7, polygon=np.array([[98.0, -1.75], [102.0, -1.75], [102.0, 5.25], [98.0, 5.25]]), width_m=4.0
    )
    return HDMap(
        name="straight", lanelets=lanes, successor_ids={1: ()}, stops=(stop, stop2), crosswalks=(cw,)
    )


@pytest.fixture(scope="session")
def straight_layers(straight_map: HDMap) -> SLayerDatabase:
    n = 401
    s = np.arange(n, dtype=float)
    curb = np.full(n, -1.75)
    curb[200:225] = -4.75
    curb[300:325] = -4.75
    return SLayerDatabase(
        hdmap=straight_map,
        centerline=Polyline(np.array([[0.0, 0.0], [400.0, 0.0]])),
        step_m=1.0,
        s_m=s,
        speed_limit_mps=np.full(n, 20 / 3.6),
        lane_left_d_m=np.full(n, 1.75),
        lane_right_d_m=np.full(n, -1.75),
        curb_right_d_m=curb,
        road_type=np.zeros(n, dtype=np.int8),
        stops=(
            RouteStop(stop=straight_map.stops[0], s_start_m=200.0, s_end_m=224.0, curb_d_m=-4.75),
            RouteStop(stop=straight_map.stops[1], s_start_m=300.0, s_end_m=324.0, curb_d_m=-4.75),
        ),
        crosswalks=(RouteCrosswalk(crosswalk=straight_map.crosswalks[0], s_start_m=98.0, s_end_m=102.0),),
    )
