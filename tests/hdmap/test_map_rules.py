"""What the loader keeps from a map's rules, on small hand-written OSM files.

Each case is a defect real maps showed: all-way-stop lines lost when only the rule names its lanelets,
``turn_direction`` taken for a driveway, a silent 50 km/h on maps without speed tags.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import MapError
from lastmile.hdmap import layers as codes
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_map
from lastmile.hdmap.routing import route
from tests.hdmap.osm_builder import ORIGIN_LAT_DEG, ORIGIN_LON_DEG, OsmBuilder, straight_lane, two_way_stop


def _load(b: OsmBuilder, tmp_path: Path, name: str = "m.osm"):
    return load_map(b.write(tmp_path / name), ORIGIN_LAT_DEG, ORIGIN_LON_DEG)


def _crossroads(b: OsmBuilder, reference_from_lanelets: bool) -> dict[str, int]:
    """Eastbound and northbound roads crossing at (0, 0), each in three lanelets, under an all-way stop."""
    rule = b.reserve()
    refs = (rule,) if reference_from_lanelets else ()
    ids = {
        "e_in": straight_lane(b, -40, 0, -5, 0, rules=refs, speed_limit="30"),
        "e_mid": straight_lane(b, -5, 0, 5, 0, left_type="virtual", right_type="virtual", speed_limit="30"),
        "e_out": straight_lane(b, 5, 0, 40, 0, speed_limit="30"),
        "n_in": straight_lane(b, 0, -40, 0, -5, rules=refs, speed_limit="30"),
        "n_mid": straight_lane(b, 0, -5, 0, 5, left_type="virtual", right_type="virtual", speed_limit="30"),
        "n_out": straight_lane(b, 0, 5, 0, 40, speed_limit="30"),
    }
    ids["e_line"] = b.way([(-5, -1.75), (-5, 1.75)], type="stop_line")
    ids["n_line"] = b.way([(1.75, -5), (-1.75, -5)], type="stop_line")
    b.relation_with_id(
        rule,
        [
            ("relation", "yield", ids["e_in"]),
            ("relation", "yield", ids["n_in"]),
            ("way", "ref_line", ids["e_line"]),
            ("way", "ref_line", ids["n_line"]),
        ],
        type="regulatory_element",
        subtype="all_way_stop",
    )
    ids["rule"] = rule
    return ids


@pytest.mark.parametrize("referenced", [True, False], ids=["lanelets-reference-rule", "only-rule-lists"])
def test_every_all_way_stop_line_is_kept_whoever_references_the_rule(
    tmp_path: Path, referenced: bool
) -> None:
    b = OsmBuilder()
    ids = _crossroads(b, reference_from_lanelets=referenced)
    hdmap = _load(b, tmp_path)
    lines = {sl.id: sl for sl in hdmap.stop_lines}
    assert set(lines) == {ids["e_line"], ids["n_line"]}
    assert lines[ids["e_line"]].lanelet_id == ids["e_in"]
    assert lines[ids["n_line"]].lanelet_id == ids["n_in"]
    assert all(sl.all_way_stop_id == ids["rule"] for sl in lines.values())
    (aws,) = hdmap.all_way_stops
    assert set(aws.stop_line_ids) == {ids["e_line"], ids["n_line"]}
    # Along the eastbound road the s-layers place the stop line at the end of the entry lanelet.
    path = route(hdmap, ids["e_in"], ids["e_out"])
    db = SLayerDatabase.build(hdmap, path)
    (rsl,) = db.stop_lines
    assert rsl.all_way_stop_id == ids["rule"] and rsl.s_m == pytest.approx(35.0, abs=0.05)
    assert set(db.intersection_type[db.lanelet_id == ids["e_mid"]].tolist()) == {codes.ALL_WAY_STOP}


def test_turn_direction_alone_makes_no_driveway(tmp_path: Path) -> None:
    """A straight lanelet tagged ``turn_direction=straight`` on a road that neither branches nor merges
    is plain road; a junction is told by the topology (and its control by the rules)."""
    b = OsmBuilder()
    a = straight_lane(b, 0, 0, 30, 0, speed_limit="30")
    mid = straight_lane(b, 30, 0, 45, 0, speed_limit="30", turn_direction="straight")
    c = straight_lane(b, 45, 0, 80, 0, speed_limit="30")
    hdmap = _load(b, tmp_path)
    assert hdmap.lanelets[mid].turn == "straight"
    db = SLayerDatabase.build(hdmap, (a, mid, c))
    assert set(db.road_type.tolist()) == {codes.NORMAL}
    assert set(db.intersection_type.tolist()) == {codes.NO_INTERSECTION}


def test_an_uncontrolled_branch_and_merge_is_a_driveway(tmp_path: Path) -> None:
    b = OsmBuilder()
    a = straight_lane(b, 0, 0, 30, 0, speed_limit="30")
    mid = straight_lane(b, 30, 0, 45, 0, speed_limit="30")
    c = straight_lane(b, 45, 0, 80, 0, speed_limit="30")
    # a side lane leaves where mid begins and another joins where it ends (sharing their end nodes)
    out_l = b.way([(30, 1.75), (37, -5), (41.75, -15)], type="line_thin")
    out_r = b.way([(30, -1.75), (34, -8), (38.25, -15)], type="line_thin")
    b.lanelet(out_l, out_r, speed_limit="30")
    in_l = b.way([(33.25, -15), (39, -5), (45, 1.75)], type="line_thin")
    in_r = b.way([(36.75, -15), (42, -6), (45, -1.75)], type="line_thin")
    b.lanelet(in_l, in_r, speed_limit="30")
    hdmap = _load(b, tmp_path)
    db = SLayerDatabase.build(hdmap, (a, mid, c))
    on_mid = db.lanelet_id == mid
    assert set(db.road_type[on_mid].tolist()) == {codes.DRIVEWAY}
    assert set(db.intersection_type[on_mid].tolist()) == {codes.UNCONTROLLED}
    assert set(db.road_type[~on_mid].tolist()) == {codes.NORMAL}


def test_a_map_without_speed_tags_has_no_speed_limit_not_fifty(tmp_path: Path) -> None:
    b = OsmBuilder()
    a = straight_lane(b, 0, 0, 30, 0)  # location=urban, no speed_limit: Lanelet2 would say 50 km/h
    c = straight_lane(b, 30, 0, 60, 0, speed_limit="20")
    hdmap = _load(b, tmp_path)
    assert math.isnan(hdmap.lanelets[a].speed_limit_mps)
    assert hdmap.lanelets[c].speed_limit_mps == pytest.approx(20 / 3.6)
    with pytest.raises(MapError, match="speed limit on every route lanelet"):
        SLayerDatabase.build(hdmap, (a, c))
    db = SLayerDatabase.build(hdmap, (a, c), unmapped_speed_limit_mps=12 / 3.6)
    on_a = db.lanelet_id == a
    np.testing.assert_allclose(db.speed_limit_mps[on_a], 12 / 3.6)
    np.testing.assert_allclose(db.speed_limit_mps[~on_a], 20 / 3.6)
    with pytest.raises(MapError, match="positive number"):
        SLayerDatabase.build(hdmap, (a, c), unmapped_speed_limit_mps=-1.0)


def test_road_border_is_a_curb_and_the_curb_two_lanes_over_counts(tmp_path: Path) -> None:
    """Two eastbound lanes: the right one ends at a road_border, the left one at a dashed line. The curb
    layer along the left lane is the border, one lane further right."""
    b = OsmBuilder()
    border = b.way([(0, -3.5), (25, -3.5), (50, -3.5)], type="road_border")
    dashed = b.way([(0, 0), (25, 0), (50, 0)], type="line_thin", subtype="dashed")
    left_edge = b.way([(0, 3.5), (25, 3.5), (50, 3.5)], type="line_thin", subtype="solid")
    right_lane = b.lanelet(dashed, border, speed_limit="30")
    left_lane = b.lanelet(left_edge, dashed, speed_limit="30")
    hdmap = _load(b, tmp_path)
    assert len(hdmap.curbs) == 1
    db_right = SLayerDatabase.build(hdmap, (right_lane,))
    np.testing.assert_allclose(db_right.curb_right_d_m, -1.75, atol=0.05)
    db_left = SLayerDatabase.build(hdmap, (left_lane,))
    np.testing.assert_allclose(db_left.lane_right_d_m, -1.75, atol=0.05)
    np.testing.assert_allclose(db_left.curb_right_d_m, -5.25, atol=0.05)


def test_right_of_way_stop_line_belongs_to_the_yielding_lanelet_only(tmp_path: Path) -> None:
    b = OsmBuilder()
    rule = b.reserve()
    main_in = straight_lane(b, -40, 0, -5, 0, rules=(rule,), speed_limit="30")
    straight_lane(b, -5, 0, 5, 0, left_type="virtual", right_type="virtual", speed_limit="30")
    side_in = straight_lane(b, 0, -40, 0, -5, rules=(rule,), speed_limit="30")
    straight_lane(b, 0, -5, -5, 0, left_type="virtual", right_type="virtual", speed_limit="30")
    line = b.way([(1.75, -5), (-1.75, -5)], type="stop_line")
    b.relation_with_id(
        rule,
        [("relation", "right_of_way", main_in), ("relation", "yield", side_in), ("way", "ref_line", line)],
        type="regulatory_element",
        subtype="right_of_way",
    )
    hdmap = _load(b, tmp_path)
    (sl,) = hdmap.stop_lines
    assert sl.lanelet_id == side_in and sl.all_way_stop_id is None and sl.signal_id is None
    assert {main_in, side_in} <= hdmap.priority_lanelet_ids


def test_tagged_stop_nodes_are_offered(tmp_path: Path) -> None:
    b = OsmBuilder()
    straight_lane(b, 0, 0, 30, 0, speed_limit="30")
    b.node(12.0, -2.5, **{"lastmile:bus_stop": "Library"})
    hdmap = _load(b, tmp_path)
    (stop,) = hdmap.tagged_stops
    assert stop.name == "Library" and stop.source == "lastmile:bus_stop"
    assert stop.x_m == pytest.approx(12.0, abs=0.05) and stop.y_m == pytest.approx(-2.5, abs=0.05)


@pytest.mark.parametrize("tag", ["fast", "-5"])
def test_a_speed_tag_lanelet2_cannot_read_is_an_error_not_zero(tmp_path: Path, tag: str) -> None:
    b = OsmBuilder()
    straight_lane(b, 0, 0, 30, 0, speed_limit=tag)
    with pytest.raises(MapError, match=f"positive speed_limit.*got '{tag}'"):
        _load(b, tmp_path)


def _plain_crossroads(b: OsmBuilder, east_rule: int | None = None) -> dict[str, int]:
    """Eastbound and northbound lanes crossing at (0, 0), no turns: only their overlap tells the junction."""
    refs = (east_rule,) if east_rule is not None else ()
    return {
        "e_in": straight_lane(b, -40, 0, -5, 0, rules=refs, speed_limit="30"),
        "e_mid": straight_lane(b, -5, 0, 5, 0, left_type="virtual", right_type="virtual", speed_limit="30"),
        "e_out": straight_lane(b, 5, 0, 40, 0, speed_limit="30"),
        "n_in": straight_lane(b, 0, -40, 0, -5, speed_limit="30"),
        "n_mid": straight_lane(b, 0, -5, 0, 5, left_type="virtual", right_type="virtual", speed_limit="30"),
        "n_out": straight_lane(b, 0, 5, 0, 40, speed_limit="30"),
    }


@pytest.mark.parametrize("control", ["none", "traffic_light", "right_of_way"])
def test_a_crossing_is_typed_by_its_control(tmp_path: Path, control: str) -> None:
    b = OsmBuilder()
    rule = b.reserve() if control != "none" else None
    ids = _plain_crossroads(b, rule)
    if rule is not None:
        line = b.way([(-5, -1.75), (-5, 1.75)], type="stop_line")
        if control == "traffic_light":
            head = b.way([(8, -3.0), (8, -2.6)], type="traffic_light", subtype="red_yellow_green", height="1")
            members = [("way", "refers", head), ("way", "ref_line", line)]
        else:
            members = [("relation", "yield", ids["e_in"]), ("relation", "right_of_way", ids["n_in"])]
            members.append(("way", "ref_line", line))
        b.relation_with_id(rule, members, type="regulatory_element", subtype=control)
    hdmap = _load(b, tmp_path)
    assert ids["n_mid"] in hdmap.conflict_ids[ids["e_mid"]]
    db = SLayerDatabase.build(hdmap, (ids["e_in"], ids["e_mid"], ids["e_out"]))
    on_mid = db.lanelet_id == ids["e_mid"]
    expected = {
        "none": (codes.DRIVEWAY, codes.UNCONTROLLED),
        "traffic_light": (codes.INTERSECTION, codes.SIGNALISED),
        "right_of_way": (codes.INTERSECTION, codes.PRIORITY),
    }[control]
    assert (set(db.road_type[on_mid].tolist()), set(db.intersection_type[on_mid].tolist())) == (
        {expected[0]},
        {expected[1]},
    )
    assert set(db.road_type[~on_mid].tolist()) == {codes.NORMAL}


@pytest.mark.parametrize("sign_type", ["de206", "us:R1-1", "stop_sign"])
def test_a_stop_signs_ref_line_is_a_stop_line_owing_a_full_stop(tmp_path: Path, sign_type: str) -> None:
    b = OsmBuilder()
    ids = two_way_stop(b, sign_type)
    hdmap = _load(b, tmp_path)
    (line,) = hdmap.stop_lines
    assert (line.id, line.lanelet_id, line.stop_sign_id) == (ids["line"], ids["in"], ids["rule"])
    assert line.all_way_stop_id is None and line.signal_id is None
    (rsl,) = SLayerDatabase.build(hdmap, (ids["in"], ids["out"])).stop_lines
    assert rsl.stop_line.stop_sign_id == ids["rule"] and rsl.s_m == pytest.approx(40.0, abs=0.05)


def test_other_signs_and_a_stop_sign_without_a_line_make_no_stop_line(tmp_path: Path) -> None:
    b = OsmBuilder()
    two_way_stop(b, "de205")  # give way: no full stop owed
    assert _load(b, tmp_path).stop_lines == ()
    b = OsmBuilder()
    two_way_stop(b, "de206", with_line=False)
    assert _load(b, tmp_path, "n.osm").stop_lines == ()


def test_a_speed_limit_rule_sets_the_limit_of_the_lanelets_that_reference_it(tmp_path: Path) -> None:
    b = OsmBuilder()
    rule = b.reserve()
    a = straight_lane(b, 0, 0, 40, 0, rules=(rule,))  # no speed_limit tag: the rule alone states it
    c = straight_lane(b, 40, 0, 80, 0, speed_limit="30")
    sign = b.way([(1, -3.0), (1, -3.6)], type="traffic_sign", subtype="de274-20")
    b.relation_with_id(rule, [("way", "refers", sign)], type="regulatory_element", subtype="speed_limit")
    hdmap = _load(b, tmp_path)
    assert hdmap.lanelets[a].speed_limit_mps == pytest.approx(20 / 3.6)
    db = SLayerDatabase.build(hdmap, (a, c))
    assert db.speed_limit_at(20.0) == pytest.approx(20 / 3.6)
    assert db.speed_limit_at(60.0) == pytest.approx(30 / 3.6)
