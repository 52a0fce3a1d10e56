"""The example route files on the two real maps in ../shared/data (skipped where it is absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lastmile.hdmap import layers as codes
from lastmile.hdmap.map_check import Status, check
from lastmile.hdmap.service_route import load_route

ROOT = Path(__file__).resolve().parents[2]
SHARED_MAPS = ROOT.parent / "shared" / "data" / "maps"
BITS_ROUTE = ROOT / "examples" / "routes" / "bits_campus_loop.toml"
EXAMPLE_ROUTE = ROOT / "examples" / "routes" / "lanelet2_example_roundabout.toml"
needs_bits = pytest.mark.skipif(
    not (SHARED_MAPS / "campus_shuttle_bits" / "lanelet2_map.osm").is_file(),
    reason="../shared/data/maps/campus_shuttle_bits is absent (real data lives beside the repository)",
)
needs_example = pytest.mark.skipif(
    not (SHARED_MAPS / "lanelet2_example" / "mapping_example.osm").is_file(),
    reason="../shared/data/maps/lanelet2_example is absent (real data lives beside the repository)",
)
WAYPOINT_NAMES = [
    "Main Gate",
    "A Block",
    "Hostel Circle",
    "CP",
    "E Block",
    "WILP Lab",
    "K-Block",
    "H-Block",
    "I-Block",
    "Security (End)",
]


@pytest.fixture(autouse=True)
def _repo_root(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)  # the example route files name the maps from the repository root


@needs_bits
def test_bits_loop_serves_the_ten_waypoint_stops_in_order() -> None:
    route = load_route(BITS_ROUTE)
    assert route.spec.projection.mgrs_grid == "44QKE"
    assert [s.name for s in route.stops] == WAYPOINT_NAMES
    assert all(s.snap.distance_m <= 1.0 for s in route.stops)  # the poses were recorded on the lane
    # One 1.58 km lanelet whose end is joined to its start across the 4.4 m gap by a connector lanelet.
    ((a, b, gap),) = route.bridged_gaps
    assert a == b == 3580 and 4.0 < gap < 5.0
    (connector,) = set(route.hdmap.lanelets) - {3580, -3580}
    assert route.lanelet_ids == (3580, connector)
    start = route.polyline.xy_m[0]
    assert route.hdmap.lanelet_at(*route.polyline.point_at(route.length_m - 2.0)[:2]) == connector
    assert route.hdmap.lanelet_at(*start) is not None  # the loop starts on road (exact test, no raster)
    assert 1580.0 < route.length_m < 1600.0
    s = [st.route_s_m for st in route.stops]
    assert s == sorted(s)  # the waypoints file lists them in driving order
    db = route.layers()
    assert len(db.s_m) == int(route.length_m)
    np.testing.assert_allclose(db.speed_limit_mps, 10 / 3.6)  # the map's speed_limit=10 (km/h)
    assert [rs.stop.id for rs in db.stops] == WAYPOINT_NAMES
    assert np.all(np.isnan(db.curb_right_d_m))  # the BITS map has lane lines, no curbs
    assert set(db.road_type.tolist()) <= {codes.NORMAL, codes.BUS_BAY}
    # Every kerbside door within the route's 0.4 m: the stops given on bends moved by a few metres.
    assert all(st.door_gap_m is not None and st.door_gap_m <= 0.4 for st in route.stops)
    off_bends = [st.moved_m for st in route.stops if st.name not in ("Main Gate", "Security (End)")]
    assert max(abs(m) for m in off_bends) <= 12.0  # those two also keep clear of the loop's start


@needs_example
def test_lanelet2_example_loop_passes_the_roundabout_arms_and_builds_its_layers() -> None:
    route = load_route(EXAMPLE_ROUTE)
    assert len(route.stops) >= 3 and all(s.snap.distance_m <= 5.0 for s in route.stops)
    assert {j.kind for j in route.junctions} == {"branch", "merge"} and len(route.junctions) >= 3
    changes = sum(
        b not in route.hdmap.successors(a)
        for a, b in zip(route.lanelet_ids, (*route.lanelet_ids[1:], route.lanelet_ids[0]), strict=True)
    )
    assert changes >= 1  # the outer lane exits at the arms: the loop needs lane changes
    db = route.layers()
    np.testing.assert_allclose(db.speed_limit_mps, 20 / 3.6)  # unmapped: the route file's limit
    assert np.isfinite(db.curb_right_d_m).mean() > 0.3  # the roundabout's kerbs are mapped
    assert (db.intersection_type == codes.UNCONTROLLED).any()
    assert [rs.stop.id for rs in db.stops] == [s.name for s in route.stops]
    # Roundabout West was given at a vertex of the polygonal roundabout (door 0.67 m off): moved.
    west = next(st for st in route.stops if st.name == "Roundabout West")
    assert west.door_gap_given_m is not None and west.door_gap_given_m > 0.4
    assert west.door_gap_m is not None and west.door_gap_m <= 0.4 and 0.0 < abs(west.moved_m) <= 12.0


@needs_example
def test_map_check_reports_layers_of_the_example_map(tmp_path: Path) -> None:
    report = check(None, None, EXAMPLE_ROUTE)
    status = {i.layer: i.status for i in report.items}
    assert not report.has_errors
    assert status["route"] is Status.OK and status["curbs"] is Status.OK
    assert status["speed limits"] is Status.MISSING  # none mapped; the route file's limit applies
    assert status["regulatory elements"] is Status.OK  # 6 traffic lights, 8 crosswalks on the map
    whole = check(SHARED_MAPS / "lanelet2_example" / "mapping_example.osm", "utm:49,8.4", None)
    item = next(i for i in whole.items if i.layer == "route")
    assert item.status is Status.MISSING and "41 lanelets" in item.detail  # the roundabout, lane changes
