"""Loading Lanelet2 files (ours and the Lanelet2 example map) and A* routing over them."""

from __future__ import annotations

from pathlib import Path

import lanelet2.routing as ll2_routing
import lanelet2.traffic_rules as ll2_rules
import numpy as np
import pytest
from lanelet2.io import Origin, loadRobust
from lanelet2.projection import UtmProjector

from lastmile.core.errors import MapError, RoutingError
from lastmile.hdmap.loader import load_campus_map, load_map
from lastmile.hdmap.routing import campus_shuttle_loop, route, route_length_m, route_polyline

EXAMPLE = (
    Path(__file__).resolve().parents[3]
    / "shared"
    / "data"
    / "maps"
    / "lanelet2_example"
    / "mapping_example.osm"
)
needs_example = pytest.mark.skipif(not EXAMPLE.is_file(), reason="shared data absent")


def test_missing_file_and_bad_origin_and_broken_xml_are_named(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="no such file"):
        load_map(tmp_path / "nope.osm", 49.0, 8.4)
    broken = tmp_path / "broken.osm"
    broken.write_text("<osm><node id='1' lat='x'")
    with pytest.raises(MapError, match=r"broken\.osm"):
        load_map(broken, 49.0, 8.4)
    with pytest.raises(MapError, match="latitude"):
        load_map(broken, float("nan"), 8.4)
    empty = tmp_path / "empty.osm"
    empty.write_text("<?xml version='1.0'?><osm version='0.6'></osm>")
    with pytest.raises(MapError, match="at least one lanelet"):
        load_map(empty, 49.0, 8.4)


def test_campus_loop_is_closed_along_successors() -> None:
    hdmap = load_campus_map()
    loop = campus_shuttle_loop(hdmap)
    assert len(set(loop)) == len(loop)
    for a, b in zip(loop, [*loop[1:], loop[0]], strict=True):
        assert b in hdmap.successors(a)
    line = route_polyline(hdmap, loop, closed=True)
    assert line.closed and abs(line.length_m - route_length_m(hdmap, loop)) < 1e-6


def test_route_errors_name_what_was_wrong() -> None:
    hdmap = load_campus_map()
    loop = campus_shuttle_loop(hdmap)
    with pytest.raises(RoutingError, match="expected a lanelet id"):
        route(hdmap, 10**9, loop[0])
    with pytest.raises(RoutingError, match="to follow"):
        route_polyline(hdmap, (loop[0], loop[2]))
    dead_end = next(
        lid for lid, succ in hdmap.successor_ids.items() if not succ and hdmap.lanelets[lid].subtype == "road"
    )
    with pytest.raises(RoutingError, match="no path"):
        route(hdmap, dead_end, loop[0])


@needs_example
def test_example_map_loads_and_astar_matches_lanelet2_shortest_path() -> None:
    """Two-way lanelets are routed in both directions, the reversed one under its negated id."""
    hdmap = load_map(EXAMPLE, 49.0, 8.4)
    assert len(hdmap.lanelets) > 300 and hdmap.stop_lines
    lmap, errors = loadRobust(str(EXAMPLE), UtmProjector(Origin(49.0, 8.4)))
    assert errors == []
    rules = ll2_rules.create(ll2_rules.Locations.Germany, ll2_rules.Participants.Vehicle)
    graph = ll2_routing.RoutingGraph(lmap, rules)
    roads = sorted(lid for lid, info in hdmap.lanelets.items() if info.subtype in {"road", "highway"})
    assert any(lid < 0 for lid in roads)  # the example map has two-way lanelets
    rng = np.random.default_rng(0)
    compared = 0
    for _ in range(1000):
        a, b = (int(v) for v in rng.choice(roads, size=2, replace=False))
        theirs = graph.shortestPath(_directed(lmap, a), _directed(lmap, b), 0, False)
        if theirs is None:
            with pytest.raises(RoutingError):
                route(hdmap, a, b)
            continue
        ours = route(hdmap, a, b)
        theirs_ids = tuple(-ll.id if ll.inverted() else ll.id for ll in theirs)
        # Ties may pick another sequence; the length must match to a millimetre.
        assert abs(route_length_m(hdmap, ours) - route_length_m(hdmap, theirs_ids)) < 1e-3
        assert ours[0] == a and ours[-1] == b
        compared += 1
    assert compared >= 60


def _directed(lmap: object, lid: int) -> object:
    lanelet = lmap.laneletLayer[abs(lid)]  # type: ignore[attr-defined]
    return lanelet.invert() if lid < 0 else lanelet
