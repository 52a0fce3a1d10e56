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
