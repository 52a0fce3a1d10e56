"""The built-in campus map: a real Lanelet2 file, regenerated bit for bit by the code in the repo."""

from __future__ import annotations

import collections
import math
from pathlib import Path

import lanelet2.routing as ll2_routing
import lanelet2.traffic_rules as ll2_rules
import numpy as np
from lanelet2.io import Origin, loadRobust
from lanelet2.projection import UtmProjector

from lastmile.hdmap import campus_layout as lay
from lastmile.hdmap.campus import write_campus_map
from lastmile.hdmap.loader import CAMPUS_OSM, load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline


def test_committed_campus_osm_is_what_the_generator_writes(tmp_path: Path) -> None:
    fresh = write_campus_map(tmp_path / "campus.osm")
    assert fresh.read_bytes() == CAMPUS_OSM.read_bytes(), "run `python -m lastmile.hdmap.campus`"


def test_lanelet2_loads_it_without_errors_and_its_routing_graph_is_valid() -> None:
    lmap, errors = loadRobust(str(CAMPUS_OSM), UtmProjector(Origin(lay.ORIGIN_LAT_DEG, lay.ORIGIN_LON_DEG)))
    assert errors == []
    rules = ll2_rules.create(ll2_rules.Locations.Germany, ll2_rules.Participants.Vehicle)
    graph = ll2_routing.RoutingGraph(lmap, rules)
    assert graph.checkValidity() == []
    subtypes = collections.Counter(ll.attributes["subtype"] for ll in lmap.laneletLayer)
    assert subtypes["crosswalk"] == 3 and subtypes["road"] >= 40
    rules_by_kind = collections.Counter(r.attributes["subtype"] for r in lmap.regulatoryElementLayer)
    assert rules_by_kind == {"all_way_stop": 1, "traffic_light": 2}


def test_ring_is_about_two_kilometres_one_lane_each_way() -> None:
    hdmap = load_campus_map()
    loop = route_polyline(hdmap, campus_shuttle_loop(hdmap), closed=True)
    assert 1900.0 < loop.length_m < 2100.0
    # The opposite lane runs beside it, 3.5 m to the left, the other way.
    for s in np.linspace(0.0, loop.length_m, 40, endpoint=False):
        x, y, h = loop.point_at(float(s))
        lid = hdmap.lanelet_at(x - 3.5 * math.sin(h), y + 3.5 * math.cos(h))
        assert lid is not None
        other = hdmap.lanelets[lid].centerline
        f = other.project(x - 3.5 * math.sin(h), y + 3.5 * math.cos(h))
        assert math.cos(other.heading_at(f.s_m) - h) < -0.9


def test_stops_have_pull_in_bays_at_the_right_curb() -> None:
    hdmap = load_campus_map()
    assert [s.id for s in hdmap.stops] == ["S1", "S2", "S3", "S4"]
    for stop in hdmap.stops:
        lane = hdmap.lanelets[stop.lane_lanelet_id].centerline
        assert abs(stop.length_m - lay.BAY_PLATFORM_M) < 0.5
        for x, y in stop.curb.xy_m:
            d = lane.project(float(x), float(y)).d_m
            assert abs(d - (-1.75 - lay.BAY_DEPTH_M)) < 0.05  # right of the lane, bay depth beyond its edge


def test_all_way_stop_t_intersection_crosswalks_parking_and_landmarks() -> None:
    hdmap = load_campus_map()
    (aws,) = hdmap.all_way_stops
    assert len(aws.entry_lanelet_ids) == 3 and len(aws.stop_line_ids) == 3
    turns = collections.Counter(ll.turn for ll in hdmap.lanelets.values())
    assert turns["left"] == 2 and turns["right"] >= 4
    assert len(hdmap.crosswalks) >= 2
    assert [a.subtype for a in hdmap.areas].count("parking") == 1
    kinds = collections.Counter(lm.kind for lm in hdmap.landmarks)
    assert kinds["light_pole"] >= 40 and kinds["building_facade"] >= 32 and kinds["sign"] >= 7
    assert len(hdmap.curbs) >= 20
    # The parking lot is reachable from the ring and the ring from the lot.
    lot_in = hdmap.lanelet_at(lay.PARK_X_M + 1.75, lay.PARK_LOT_Y_M - 5.0)
    lot_out = hdmap.lanelet_at(lay.PARK_X_M - 1.75, lay.PARK_LOT_Y_M - 5.0)
    assert lot_in is not None and lot_out is not None
    assert hdmap.successors(lot_in) == () and hdmap.successors(lot_out) != ()
