"""The amcl mode's occupancy map: built from map points in the height band, written and read back as
ROS map_server files, the planar scan of a cloud, and bad files or settings as one line."""

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError, MapError
from lastmile.core.perception_mode import PerceptionMode
from lastmile.localization.amcl_localization import AmclSettings
from lastmile.localization.occupancy_map import grid_from_points, planar_scan, read_grid, write_grid
from lastmile.stack.stack_settings import LocalizationMode, StackSettings


def _wall_points() -> np.ndarray:
    # A wall along y = 5 from x = 0 to 10, 0 to 3 m high, and road points (z = 0) everywhere below it.
    xs, zs = np.meshgrid(np.arange(0.0, 10.0, 0.05), np.arange(0.0, 3.0, 0.1))
    wall = np.c_[xs.ravel(), np.full(xs.size, 5.0), zs.ravel()]
    road = np.c_[np.random.default_rng(0).uniform(0, 10, (500, 2)), np.zeros(500)]
    return np.vstack([wall, road])


def test_the_band_above_the_road_is_occupied_and_survives_the_round_trip(tmp_path: Path) -> None:
    grid = grid_from_points(_wall_points(), resolution_m=0.1)
    occ = np.asarray(grid.occupied)
    rows, cols = np.nonzero(occ)
    ys = grid.origin_xy[1] + (rows + 0.5) * 0.1
    assert np.all(np.abs(ys - 5.0) < 0.1)  # only the wall; the road is not an obstacle
    assert cols.max() - cols.min() >= 98
    pgm = write_grid(tmp_path / "campus.yaml", grid)
    assert pgm.read_bytes().startswith(b"P5\n")
    back = read_grid(tmp_path / "campus.yaml")
    assert np.array_equal(np.asarray(back.occupied), occ)
    assert back.origin_xy == pytest.approx(grid.origin_xy) and back.resolution_m == 0.1


def test_a_planar_scan_keeps_the_nearest_return_per_degree_at_its_own_bearing() -> None:
    pts = np.array(
        [
            [10.0, 0.05, 1.0],  # nearest in its bin
            [12.0, 0.06, 1.0],  # behind it, same bin
            [0.0, 4.0, 1.0],
            [3.0, 0.0, 0.1],  # road: below the band
            [0.0, -6.0, 4.0],  # canopy: above it
        ]
    )
    ranges, angles = planar_scan(pts)
    order = np.argsort(angles)
    np.testing.assert_allclose(ranges[order], [math.hypot(10.0, 0.05), 4.0])
    np.testing.assert_allclose(angles[order], [math.atan2(0.05, 10.0), math.pi / 2])


def test_bad_occupancy_files_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="no such file"):
        read_grid(tmp_path / "none.yaml")
    (tmp_path / "a.yaml").write_text("image: a.pgm\nresolution: 0.1\n")
    with pytest.raises(MapError, match="expected key 'origin'"):
        read_grid(tmp_path / "a.yaml")
    (tmp_path / "b.yaml").write_text("image: b.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    (tmp_path / "b.pgm").write_bytes(b"P2\n2 2\n255\n0 0 0 0\n")
    with pytest.raises(MapError, match=r"expected a binary PGM \(P5\)"):
        read_grid(tmp_path / "b.yaml")


def test_amcl_is_refused_at_configuration_time_with_radar_or_without_a_map() -> None:
    with pytest.raises(ConfigError, match="expected raw LiDAR perception"):
        StackSettings(localization=LocalizationMode.AMCL, perception=PerceptionMode.RADAR_TRACKING)
    with pytest.raises(ConfigError, match=r"stack.amcl.map: expected the occupancy map .* got none"):
        StackSettings(localization=LocalizationMode.AMCL)
    with pytest.raises(ConfigError, match=r"stack.amcl.map: .*none.yaml: expected an occupancy map"):
        StackSettings(localization=LocalizationMode.AMCL, amcl=AmclSettings(map="none.yaml"))
