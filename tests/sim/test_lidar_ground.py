"""The simulated ground: a curb step only where the map draws a curb."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lastmile.hdmap.loader import load_projected_map
from lastmile.hdmap.projection import MapProjection, ProjectionKind
from lastmile.hdmap.service_route import load_route
from lastmile.sim.lidar_ground import SIDEWALK_M, VERGE_M, GroundRaster
from tests.hdmap.osm_builder import ORIGIN_LAT_DEG, ORIGIN_LON_DEG, OsmBuilder, straight_lane

UTM = MapProjection(kind=ProjectionKind.UTM, origin_lat_deg=ORIGIN_LAT_DEG, origin_lon_deg=ORIGIN_LON_DEG)
ROUTE = Path(__file__).resolve().parents[2] / "examples" / "routes" / "town_block_loop.toml"


def _road(g: GroundRaster, *xy: tuple[float, float]) -> list[bool]:
    pts = np.asarray(xy, dtype=float)
    return g.is_road(pts[:, 0], pts[:, 1]).tolist()


def test_a_junction_s_uncovered_wedge_is_road_and_a_curb_still_steps() -> None:
    """At North St / East Ave the right-turn and left-turn lanelets part and leave a wedge no lanelet
    covers: paved, at road level (it stood as a curb-high island, and the raw stack braked for it).
    Behind the mapped curbs of the streets the sidewalk is raised."""
    g = GroundRaster(load_route(ROUTE).hdmap)
    assert _road(g, (191.0, 119.9), (192.0, 120.0), (195.0, 120.0)) == [True, True, True]
    # West Avenue's east curb is at x = 3.5: the sidewalk behind it, within SIDEWALK_M, is raised.
    assert _road(g, (3.4, 60.0), (3.6, 60.0), (3.5 + SIDEWALK_M - 0.1, 60.0)) == [True, False, False]
    # Far from every road, raised ground (the verge only runs beside boundaries that are no curb).
    assert _road(g, (50.0, 60.0)) == [False]


def test_a_lane_drawn_without_curbs_has_no_step_beside_it(tmp_path: Path) -> None:
    """A map that draws its lane edges as paint (the BITS loop has no curbs at all): the ground beside
    the lane stays at road level for VERGE_M (a step there was a row of objects the stack could not
    explain with any mapped curb)."""
    b = OsmBuilder()
    straight_lane(b, 0.0, 0.0, 60.0, 0.0)  # 3.5 m wide, line_thin both sides
    hdmap = load_projected_map(b.write(tmp_path / "map.osm"), UTM)
    g = GroundRaster(hdmap)
    edge = -1.75
    assert _road(g, (30.0, edge - 0.5), (30.0, edge - VERGE_M + 0.2)) == [True, True]
    assert _road(g, (30.0, edge - VERGE_M - 0.5)) == [False]


def test_a_curb_far_from_every_lanelet_is_no_error(tmp_path: Path) -> None:
    """The raster covers the lanelets; a mapped curb beyond it (the Lanelet2 example has them) is
    skipped (its sidewalk band fell wholly outside the raster and the fill asked for a negative size)."""
    b = OsmBuilder()
    straight_lane(b, 0.0, 0.0, 60.0, 0.0)
    b.way([(200.0, 1.0), (230.0, 1.0)], type="curbstone")  # beside the raster, in its rows
    hdmap = load_projected_map(b.write(tmp_path / "map.osm"), UTM)
    assert len(hdmap.curbs) >= 1
    g = GroundRaster(hdmap)
    assert _road(g, (30.0, 0.0)) == [True]
