"""The give-way rule on the example town's give-way line (North St yields to East Ave, lanelet 961's
line at x = 190): the conflict zone from the map, stop or go from the tracks, and two-way stops."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest

from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects, empty_tracks
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.decision.give_way_config import GiveWayConfig
from lastmile.decision.give_way_rule import GiveWayRule
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig
from lastmile.hdmap.give_way_zones import YieldKind
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.service_route import load_route

ROUTE = "examples/routes/town_block_loop.toml"
SOUTHBOUND_X_M = 198.25
"""East Avenue's southbound lane centre: the lane the shuttle turns right into."""
NORTHBOUND_X_M = 201.75
ZONE_START_Y_M = 117.4
"""Where the southbound lane enters the right turn's area (North St's lane ends at y 116.5-120)."""
G = VehicleGeometry()
LINES = TrafficLightRuleConfig()


@functools.cache
def _town_layers() -> SLayerDatabase:
    return load_route(ROUTE).layers()


def _two_way_stop(layers: SLayerDatabase) -> SLayerDatabase:
    """The town with its give-way line made a stop sign's (and no right-of-way rule)."""
    lines = tuple(
        dataclasses.replace(
            rl,
            stop_line=dataclasses.replace(rl.stop_line, right_of_way_id=None, stop_sign_id=1),
        )
        if rl.stop_line.right_of_way_id is not None
        else rl
        for rl in layers.stop_lines
    )
    hdmap = dataclasses.replace(layers.hdmap, right_of_way_rules=())
    return dataclasses.replace(layers, stop_lines=lines, hdmap=hdmap)


def _cars(*rows: tuple[float, float, float]) -> TrackedObjects:
    """Cars at (x, y) driving ``vy`` north (negative: south)."""
    table = np.zeros((len(rows), len(TRACK_COLUMNS)))
    for k, (x, y, vy) in enumerate(rows):
        yaw = -math.pi / 2 if vy < 0 else math.pi / 2
        table[k, :8] = (x, y, 0.0, vy, 4.5, 1.8, yaw, float(ObjectClass.CAR))
    return TrackedObjects(stamp=Stamp(0), ids=np.arange(len(rows), dtype=np.int64) + 7, table=table)


def _line_s(rule: GiveWayRule) -> float:
    (j,) = rule.junctions
    return j.line_s_m


def _step(rule: GiveWayRule, ahead_m: float, speed_mps: float, tracks: TrackedObjects, t_s: float = 0.0):  # type: ignore[no-untyped-def]
    route = rule.layers.centerline
    front = _line_s(rule) - ahead_m
    return rule.step(t_s, front, speed_mps, 20.0 / 3.6, tracks, lambda s, f: route.ds_m(f, s))


def test_the_map_gives_one_give_way_junction_whose_zone_is_the_southbound_lane() -> None:
    rule = GiveWayRule(_town_layers(), G)
    (j,) = rule.junctions
    assert j.kind is YieldKind.GIVE_WAY and j.name == "North St / East Ave" and j.turn == "right"
    (zone,) = j.zones  # the right turn merges into the southbound lane; the northbound one is clear of it
    priority = rule.layers.hdmap.lanelets[zone.priority_lanelet_id].centerline
    assert priority.xy_m[0][1] > priority.xy_m[-1][1]  # a southbound lanelet
    assert 3.0 < zone.start_after_line_m < zone.end_after_line_m < 15.0
    assert all(a.centerline.length_m > 60.0 for a in zone.approaches)  # East Ave north of the junction


def test_an_empty_priority_road_lets_the_shuttle_through_without_stopping() -> None:
    rule = GiveWayRule(_town_layers(), G)
    verdict = _step(rule, 20.0, 4.0, empty_tracks(Stamp(0)))
    assert verdict.stop_front_s_m is None and verdict.why.endswith(": gap")


def test_a_car_arriving_within_the_gap_stops_the_shuttle_at_the_line() -> None:
    rule = GiveWayRule(_town_layers(), G)
    # 40 m north of the zone at 8 m/s: 4.7 s, under the 6.2 s right turn's critical gap.
    verdict = _step(rule, 20.0, 4.0, _cars((SOUTHBOUND_X_M, ZONE_START_Y_M + 40.0, -8.0)))
    assert verdict.stop_front_s_m == pytest.approx(_line_s(rule) - LINES.stop_before_line_m)
    assert verdict.track_id == 7 and verdict.conflicts == 1
    assert "give way to 1 road user at North St / East Ave" in verdict.why


def test_the_gap_needed_is_the_shuttles_own_clearance_when_that_is_longer_than_hcms() -> None:
    # Standing at the line, the shuttle needs ~7 s from rest at 0.8 m/s^2 to clear the zone with its
    # whole body, plus the 1.5 s margin: a car 7.5 s away (beyond HCM's 6.2 s) still holds it.
    rule = GiveWayRule(_town_layers(), G)
    away = ZONE_START_Y_M + 2.25 + 8.0 * 7.5
    held = _step(rule, LINES.stop_before_line_m, 0.0, _cars((SOUTHBOUND_X_M, away, -8.0)))
    assert held.stop_front_s_m is not None
    need = float(held.why.split("gap needed ")[1].split(" s")[0])
    assert need > GiveWayConfig().critical_gap_right_s
    # A car beyond what is needed lets it go.
    far = ZONE_START_Y_M + 2.25 + 8.0 * (need + 1.0)
    assert (
        _step(rule, LINES.stop_before_line_m, 0.0, _cars((SOUTHBOUND_X_M, far, -8.0))).stop_front_s_m is None
    )


def test_standing_cars_away_from_the_zone_and_the_other_lane_do_not_hold_it() -> None:
    rule = GiveWayRule(_town_layers(), G)
    tracks = _cars(
        (SOUTHBOUND_X_M, ZONE_START_Y_M + 20.0, 0.0),  # parked upstream: never arrives
        (NORTHBOUND_X_M, ZONE_START_Y_M - 30.0, 8.0),  # northbound: not in the right turn's way
    )
    assert _step(rule, 10.0, 3.0, tracks).stop_front_s_m is None


def test_a_car_standing_in_the_zone_holds_it() -> None:
    rule = GiveWayRule(_town_layers(), G)
    verdict = _step(rule, 1.0, 0.0, _cars((SOUTHBOUND_X_M, ZONE_START_Y_M - 3.0, 0.0)))
    assert verdict.stop_front_s_m is not None and "first in 0.0 s" in verdict.why


def test_a_car_seen_too_late_to_stop_at_the_line_is_given_way_to_short_of_the_zone() -> None:
    rule = GiveWayRule(_town_layers(), G)
    (j,) = rule.junctions
    late = _cars((SOUTHBOUND_X_M, ZONE_START_Y_M + 30.0, -8.0))
    # 4 m before the line at 4 m/s: ~7 m to stop comfortably, too far for the line, not for the zone.
    verdict = _step(rule, 4.0, 4.0, late)
    hold = j.line_s_m + min(z.start_after_line_m for z in j.zones) - GiveWayConfig().zone_margin_m
    assert verdict.stop_front_s_m == pytest.approx(hold) and "short of the conflict zone" in verdict.why


def test_once_it_cannot_stop_short_of_the_zone_it_is_committed() -> None:
    rule = GiveWayRule(_town_layers(), G)
    assert _step(rule, 1.0, 4.0, empty_tracks(Stamp(0))).why.endswith("committed")
    late = _cars((SOUTHBOUND_X_M, ZONE_START_Y_M + 30.0, -8.0))
    verdict = _step(rule, 0.5, 4.0, late)
    assert verdict.stop_front_s_m is None and verdict.why.endswith("committed")
    # Past the junction and back to the line a lap later: judged afresh.
    assert _step(rule, 200.0, 4.0, late).why == ""
    assert _step(rule, 20.0, 4.0, late).stop_front_s_m is not None


def test_a_car_that_leaves_the_radars_view_is_still_expected_until_it_has_passed() -> None:
    rule = GiveWayRule(_town_layers(), G)
    # 30 m from the zone at 8 m/s: it arrives in 3.75 s and has left the zone (7.4 m + 4.5 m) 1.5 s later.
    seen = _cars((SOUTHBOUND_X_M, ZONE_START_Y_M + 2.25 + 30.0, -8.0))
    assert _step(rule, LINES.stop_before_line_m, 0.0, seen, t_s=10.0).stop_front_s_m is not None
    none = empty_tracks(Stamp(0))
    held = _step(rule, LINES.stop_before_line_m, 0.0, none, t_s=12.0)
    assert held.stop_front_s_m is not None and held.track_id == 7
    assert float(held.why.split("first in ")[1].split(" s")[0]) == pytest.approx(3.75 - 2.0, abs=0.06)
    assert _step(rule, LINES.stop_before_line_m, 0.0, none, t_s=15.5).stop_front_s_m is None


def test_switched_off_the_rule_finds_no_junctions() -> None:
    rule = GiveWayRule(_town_layers(), G, GiveWayConfig(enabled=False))
    assert rule.junctions == ()
    route = rule.layers.centerline
    tracks = _cars((SOUTHBOUND_X_M, ZONE_START_Y_M + 10.0, -8.0))
    line_s = _line_s(GiveWayRule(_town_layers(), G))
    assert (
        rule.step(0.0, line_s - 9.0, 3.0, 5.0, tracks, lambda s, f: route.ds_m(f, s)).stop_front_s_m is None
    )


def test_a_two_way_stop_yields_to_the_road_without_a_line_from_rest() -> None:
    rule = GiveWayRule(_two_way_stop(_town_layers()), G)
    (j,) = rule.junctions
    assert j.kind is YieldKind.STOP_SIGN
    assert len(j.zones) == 1  # East Ave's southbound lane has no line: it has priority
    # Still 20 m out at speed, the gap is judged from rest at the line: the same car holds it there.
    car = _cars((SOUTHBOUND_X_M, ZONE_START_Y_M + 2.25 + 8.0 * 7.0, -8.0))
    moving, standing = _step(rule, 20.0, 5.0, car), _step(rule, LINES.stop_before_line_m, 0.0, car)
    assert moving.stop_front_s_m is not None and standing.stop_front_s_m is not None
    assert (
        moving.why.startswith("stop sign")
        and moving.why.split("gap needed")[1] == standing.why.split("gap needed")[1]
    )
