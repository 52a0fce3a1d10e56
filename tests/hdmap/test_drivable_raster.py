"""The drivable raster's verdicts by one flat look-up equal the two-axis look-up they replaced."""

from __future__ import annotations

import numpy as np

from lastmile.hdmap.drivable import DrivableRaster


def _two_axis_classify(raster: DrivableRaster, xy: np.ndarray) -> np.ndarray:
    """The former ``classify``: a finiteness test per point and a gather on both axes."""
    cells = np.floor((xy - raster.origin) / raster.cell_m)
    nx, ny = raster.grid.shape
    ok = (cells[:, 0] >= 0) & (cells[:, 0] < nx) & (cells[:, 1] >= 0) & (cells[:, 1] < ny)
    ok &= np.isfinite(cells).all(axis=1)
    out = np.full(len(cells), DrivableRaster.OUTSIDE, dtype=np.int8)
    idx = cells[ok].astype(int)
    out[ok] = raster.grid[idx[:, 0], idx[:, 1]]
    return out


def test_flat_look_up_equals_the_two_axis_one_on_and_off_the_raster_and_for_non_finite_points() -> None:
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 6.0], [0.0, 6.0]])
    triangle = np.array([[12.0, 1.0], [20.0, 1.0], [16.0, 9.0]])
    raster = DrivableRaster([square, triangle])
    g = np.random.default_rng(0)
    xy = g.uniform(-5.0, 25.0, (20_000, 2))
    xy[:6] = [[np.nan, 1.0], [1.0, np.nan], [np.inf, 1.0], [-np.inf, 1.0], [1.0, np.inf], [1e300, -1e300]]
    verdict = raster.classify(xy)
    assert verdict.dtype == np.int8
    assert np.array_equal(verdict, _two_axis_classify(raster, xy))
    assert set(np.unique(verdict)) == {DrivableRaster.OUTSIDE, DrivableRaster.INSIDE, DrivableRaster.EDGE}
    assert np.array_equal(raster.classify_cells(raster.cell_index(xy)), verdict)
    empty = DrivableRaster([])
    assert np.array_equal(empty.classify(xy[:10]), np.zeros(10, dtype=np.int8))


def test_one_point_at_a_time_gives_the_vectorised_verdict_also_for_non_finite_points() -> None:
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 6.0], [0.0, 6.0]])
    raster = DrivableRaster([square])
    xy = np.random.default_rng(1).uniform(-3.0, 13.0, (5_000, 2))
    xy[:6] = [[np.nan, 1.0], [1.0, np.nan], [np.inf, 1.0], [-np.inf, 1.0], [1.0, np.inf], [1e300, -1e300]]
    one_by_one = [raster.classify_point(x, y) for x, y in xy.tolist()]
    assert one_by_one == raster.classify(xy).tolist()


def test_the_maps_few_point_drivable_test_equals_its_vectorised_one() -> None:
    from lastmile.hdmap.loader import load_campus_map
    from lastmile.hdmap.model import _FEW_POINTS

    hdmap = load_campus_map()
    # Points around the road network, many within a cell of a lanelet edge (the exact test's cases).
    lo, hi = hdmap._boxes[1].min(axis=0), hdmap._boxes[2].max(axis=0)
    xy = np.random.default_rng(2).uniform(lo, hi, (4_000, 2))
    vectorised = hdmap.is_drivable(xy)
    few = np.concatenate([hdmap.is_drivable(xy[k : k + _FEW_POINTS]) for k in range(0, len(xy), _FEW_POINTS)])
    assert few.dtype == bool and np.array_equal(few, vectorised)
    assert 0 < vectorised.sum() < len(xy)
