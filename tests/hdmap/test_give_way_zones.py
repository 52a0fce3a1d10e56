"""Right-of-way rules read from Lanelet2, and which lines make a route yield (the example town)."""

from __future__ import annotations

import functools
import math

import numpy as np

from lastmile.core.polyline import Polyline
from lastmile.hdmap.give_way_zones import YieldKind, movement, yield_kind
from lastmile.hdmap.model import HDMap, LaneletInfo, StopLine
from lastmile.hdmap.service_route import load_route

ROUTE = "examples/routes/town_block_loop.toml"


@functools.cache
def _town() -> HDMap:
    return load_route(ROUTE).hdmap


def test_the_towns_right_of_way_rule_is_read_with_its_priority_and_yielding_lanelets() -> None:
    hdmap = _town()
    (rule,) = hdmap.right_of_way_rules
    assert rule.name == "North St / East Ave"
    (line,) = [sl for sl in hdmap.stop_lines if sl.right_of_way_id is not None]
    assert line.right_of_way_id == rule.id and rule.stop_line_id == line.id
    # East Avenue's through movements have priority; North Street's lanes and turns yield.
    for lid in rule.priority_lanelet_ids:
        ll = hdmap.lanelets[lid]
        assert ll.turn == "straight" and abs(float(np.mean(ll.centerline.xy_m[:, 0])) - 200.0) < 2.5
    assert {hdmap.lanelets[lid].turn for lid in rule.yield_lanelet_ids} == {"", "left", "right"}
    assert set(rule.priority_lanelet_ids) | set(rule.yield_lanelet_ids) == set(hdmap.priority_lanelet_ids)


def test_only_give_way_lines_and_two_way_stops_make_the_route_yield() -> None:
    xy = np.zeros((2, 2))
    assert yield_kind(StopLine(id=1, line=xy, lanelet_id=1, right_of_way_id=3)) is YieldKind.GIVE_WAY
    assert yield_kind(StopLine(id=1, line=xy, lanelet_id=1, stop_sign_id=3)) is YieldKind.STOP_SIGN
    # An all-way stop's or a signal's line (even one a stop sign also names) is their own rules'.
    assert yield_kind(StopLine(id=1, line=xy, lanelet_id=1, all_way_stop_id=2, stop_sign_id=3)) is None
    assert yield_kind(StopLine(id=1, line=xy, lanelet_id=1, signal_id=2)) is None
    assert yield_kind(StopLine(id=1, line=xy, lanelet_id=1)) is None


def _lanelet(turn_rad: float, tag: str = "") -> LaneletInfo:
    a = np.linspace(0.0, turn_rad, 10)
    r = 10.0
    centre = np.c_[r * np.sin(a), r * (1 - np.cos(a))] if turn_rad else np.c_[np.linspace(0, 10, 10), 0 * a]
    line = Polyline(centre)
    return LaneletInfo(
        id=1, centerline=line, left=line.offset(1.75), right=line.offset(-1.75), speed_limit_mps=5.0, turn=tag
    )


def test_the_routes_movement_is_the_turn_tag_else_the_heading_change() -> None:
    assert movement(_lanelet(math.pi / 2)) == "left"
    assert movement(_lanelet(-math.pi / 2)) == "right"
    assert movement(_lanelet(0.0)) == "straight"
    assert movement(_lanelet(math.pi / 2, tag="straight")) == "straight"
