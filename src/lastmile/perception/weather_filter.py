"""Snow and rain point removal: dynamic-radius outlier removal (DROR, Charron et al. 2018).

A falling flake returns an isolated point near the sensor, while a surface at the same range
returns many neighbours. A fixed search radius would delete sparse far objects, so the radius grows
with range as the beam spacing does: ``radius = max(min_radius_m, multiplier * range * azimuth_step)``.
A point with fewer than ``min_neighbours`` other points inside its radius is removed.

Exact shortcut: a point whose neighbours along its own scan line (same sensor and ring, next in
firing order = azimuth order) already give it ``min_neighbours`` points inside its radius surely
passes and skips the neighbour search; only the rest (ends of ring segments, sparse points: where
snow lives) are searched, in a bucket grid of side ``r_max`` (compiled kernels in
:mod:`lastmile.perception.dror_kernel`; the mask equals a KD-tree query's bit for bit).

Scan pattern: the radius follows the horizontal column spacing, but a LiDAR's rings are often much
farther apart (a 16-ring blind-spot unit: 3.3 deg against 0.4 deg columns), so an object seen by
only one or two columns (a car's end glimpsed past the bus) is a vertical row of points one ring
apart, each with fewer neighbours inside the radius than a flake among flakes. Given each point's
LiDAR and ring (``scan_grid``), a point that fails is kept when the scan's own neighbourhood holds
``scan_min_neighbours`` returns at its range: points of the same LiDAR on its ring or the
``ring_reach`` rings either side, within the radius's angular width in azimuth (``multiplier``
columns), whose horizontal range from the LiDAR differs from its own by at most its radius (and
whose height one ring spacing per ring apart can reach). A flake's scan neighbours are the
background behind it (a different range), so it still goes: precipitation echoes are scattered at
random, and two more at the same range within a few columns and rings of one flake are rare (a few
hundred echoes per sweep over 360 deg x 16-32 rings x ~10 m of range: ~1e-2 expected per flake).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError, MessageError
from lastmile.perception.dror_kernel import (
    dror_columns,
    enough_neighbours,
    first_of_each_value,
    scan_line_sure,
    scan_window_counts,
)


@dataclass(frozen=True, slots=True, kw_only=True)
class DrorConfig:
    """Attributes:
    azimuth_step_rad: the LiDAR's horizontal angular resolution (0.2 deg at 10 Hz for a typical
        32-channel unit); with per-point steps given (a rig of mixed units), the floor of those.
    multiplier: beta of DROR, how many beam spacings the radius spans (the paper uses 3; 5 keeps
        the end points of thin objects' ring segments, measured on synthetic scans: object points
        kept 92 % vs 90 %, flakes removed 96 % vs 98 %).
    min_radius_m: radius floor near the sensor.
    min_neighbours: k_min, neighbours (excluding the point) a kept point needs.
    max_range_m: points beyond are kept untested: snowflakes and raindrops return near the sensor
        (a flake is too small to return a detectable echo from far), and testing only the near
        field keeps the filter within the frame budget.
    """

    azimuth_step_rad: float = math.radians(0.2)
    multiplier: float = 5.0
    min_radius_m: float = 0.1
    min_neighbours: int = 3
    max_range_m: float = 20.0
    ring_reach: int = 2
    scan_min_neighbours: int = 2
    ring_spacing_rad: float = math.radians(3.4)

    def __post_init__(self) -> None:
        for name in ("azimuth_step_rad", "multiplier", "min_radius_m", "max_range_m", "ring_spacing_rad"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"DrorConfig.{name}: expected a positive number, got {v}")
        if self.min_neighbours < 1:
            raise ConfigError(f"DrorConfig.min_neighbours: expected >= 1, got {self.min_neighbours}")
        if self.ring_reach < 0 or self.scan_min_neighbours < 1:
            raise ConfigError(
                "DrorConfig: expected ring_reach >= 0 and scan_min_neighbours >= 1, got "
                f"{self.ring_reach}, {self.scan_min_neighbours}"
            )


def dror_keep_mask(
    xyz_m: npt.ArrayLike,
    config: DrorConfig | None = None,
    sensor_xy_m: npt.ArrayLike | None = None,
    scan_key: npt.ArrayLike | None = None,
    azimuth_step_rad: npt.ArrayLike | None = None,
    scan_grid: npt.ArrayLike | None = None,
) -> npt.NDArray[np.bool_]:
    """(N,) bool, True for points DROR keeps.

    Args:
        xyz_m: (N, 3) points.
        config: filter parameters.
        sensor_xy_m: (N, 2) horizontal position of the LiDAR that measured each point (ranges are
            measured from it); None measures from the origin.
        scan_key: (N,) int, e.g. ``sensor_index * 1000 + ring``: points sharing a key lie on one
            scan line, listed in firing order. When given, a point with ``min_neighbours``
            scan-line neighbours (the next ones in that order on each side) inside its radius is
            kept without a neighbour search; the result is the same, only faster.
        azimuth_step_rad: (N,) horizontal resolution of the LiDAR that measured each point
            (:func:`azimuth_step_from_times`); a coarser unit gets a proportionally wider radius,
            or a blind-spot unit's sparser columns would lose thin objects with the snow. None:
            ``config.azimuth_step_rad`` for every point; given steps are floored at it.
        scan_grid: (N, 2) int ``sensor, ring`` of each point, rings numbered in elevation order
            (ring + 1 is the next beam up, as LiDAR drivers number them). When given, a point the
            radius test removes is kept if its scan neighbourhood holds ``scan_min_neighbours`` points
            at its range (module docstring; ``config.ring_reach``). Needs ``sensor_xy_m`` when the
            LiDARs are not at the origin.
    """
    cfg = config or DrorConfig()
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    n = len(p)
    keep = np.ones(n, dtype=bool)
    if n == 0:
        return keep
    if sensor_xy_m is None:
        dx, dy = p[:, 0], p[:, 1]
    else:
        s = np.asarray(sensor_xy_m, dtype=np.float64)
        if s.shape != (n, 2):
            raise MessageError(f"dror_keep_mask.sensor_xy_m: expected ({n}, 2), got {s.shape}")
        dx, dy = p[:, 0] - s[:, 0], p[:, 1] - s[:, 1]
    rng = np.hypot(dx, dy)
    step: float | np.ndarray = cfg.azimuth_step_rad
    if azimuth_step_rad is not None:
        given = np.asarray(azimuth_step_rad, dtype=np.float64).reshape(-1)
        if given.shape != (n,) or not np.isfinite(given).all():
            raise MessageError(f"dror_keep_mask.azimuth_step_rad: expected ({n},) finite, got {given.shape}")
        step = np.maximum(given, cfg.azimuth_step_rad)
    radius = np.maximum(cfg.min_radius_m, cfg.multiplier * rng * step)
    key = None
    if scan_key is not None:
        key = np.asarray(scan_key).reshape(-1)
        if key.shape != (n,):
            raise MessageError(f"dror_keep_mask.scan_key: expected ({n},), got {key.shape}")
        key = key.astype(np.int64)
    grid = None
    if scan_grid is not None:
        grid = np.asarray(scan_grid)
        if grid.shape != (n, 2) or not np.issubdtype(grid.dtype, np.integer):
            raise MessageError(
                f"dror_keep_mask.scan_grid: expected ({n}, 2) int, got {grid.shape} {grid.dtype}"
            )
        grid = grid.astype(np.int64)
    # The compiled kernels read columns.
    x, y, z = (np.ascontiguousarray(p[:, i]) for i in range(3))
    return _dror_mask(
        cfg,
        x,
        y,
        z,
        dx,
        dy,
        rng,
        radius,
        key,
        None if grid is None else grid[:, 0],
        None if grid is None else grid[:, 1],
    )


def dror_keep_rows(
    xyz_m: np.ndarray,
    points: np.ndarray,
    rows: np.ndarray,
    unit_xy_m: np.ndarray,
    unit_step_rad: np.ndarray,
    config: DrorConfig | None = None,
) -> npt.NDArray[np.bool_]:
    """(M,) bool, True for the ``rows`` of a merged cloud DROR keeps: :func:`dror_keep_mask` of
    those rows with each point's LiDAR position, column step, scan key ``sensor * 1000 + ring``
    and scan grid ``sensor, ring`` taken from its sensor index, gathered in one compiled pass
    (``dror_kernel.dror_columns``) instead of a dozen array expressions over the rows.

    Args:
        xyz_m: (N, 3) float64 coordinates of the cloud.
        points: (N, >= 6) float32 merged cloud (:data:`merge.MERGED_COLUMNS`: ring in column 4,
            sensor index in column 5).
        rows: (M,) int64 rows tested (e.g. the non-ground points).
        unit_xy_m: (S, 2) horizontal position of each LiDAR, by sensor index.
        unit_step_rad: (S,) each LiDAR's horizontal resolution (:func:`azimuth_step_from_times`),
            floored at ``config.azimuth_step_rad``.
    """
    cfg = config or DrorConfig()
    rows = np.asarray(rows, dtype=np.int64)
    unit_xy = np.ascontiguousarray(unit_xy_m, dtype=np.float64)
    unit_step = np.ascontiguousarray(unit_step_rad, dtype=np.float64).reshape(-1)
    if unit_xy.ndim != 2 or unit_xy.shape[1] != 2 or unit_step.shape != (len(unit_xy),):
        raise MessageError(
            f"dror_keep_rows: expected (S, 2) positions and (S,) steps, got {unit_xy.shape} and "
            f"{unit_step.shape}"
        )
    if not (np.isfinite(unit_xy).all() and np.isfinite(unit_step).all()):
        raise MessageError("dror_keep_rows: expected finite LiDAR positions and steps, got NaN or inf")
    if len(rows) == 0:
        return np.ones(0, dtype=bool)
    x, y, z, dx, dy, rng, radius, key, sensor, ring = dror_columns(
        np.ascontiguousarray(xyz_m, dtype=np.float64),
        points,
        rows,
        unit_xy,
        unit_step,
        cfg.azimuth_step_rad,
        cfg.multiplier,
        cfg.min_radius_m,
    )
    return _dror_mask(cfg, x, y, z, dx, dy, rng, radius, key, sensor, ring)


def _dror_mask(
    cfg: DrorConfig,
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    rng: np.ndarray,
    radius: np.ndarray,
    key: np.ndarray | None,
    sensor: np.ndarray | None,
    ring: np.ndarray | None,
) -> npt.NDArray[np.bool_]:
    """DROR's verdicts from its per-point inputs (:func:`dror_keep_mask`'s steps after the radius):
    the scan-line shortcut (with ``key``), the neighbour count of the rest within ``max_range_m``,
    and the scan-pattern test of the removed ones (with ``sensor`` and ``ring``)."""
    n = len(x)
    keep = np.ones(n, dtype=bool)
    candidate = rng <= cfg.max_range_m
    sure = np.zeros(n, dtype=bool)
    if key is not None:
        sure = scan_line_sure(x, y, z, key, radius, cfg.min_neighbours)
    test = np.flatnonzero(candidate & ~sure)
    if len(test) == 0:
        return keep
    # Only points that can lie within a tested point's radius are candidate neighbours.
    r_max = float(radius[test].max())
    pool = np.flatnonzero(rng <= cfg.max_range_m + r_max)
    keep[test] = enough_neighbours(x, y, z, pool, test, radius, r_max, cfg.min_neighbours)
    if sensor is not None and ring is not None and cfg.ring_reach > 0:
        failed = test[~keep[test]]
        if len(failed):
            count = _scan_neighbours(
                sensor,
                ring,
                np.arctan2(dy, dx),
                rng,
                z,
                radius,
                failed,
                cfg.ring_reach,
                cfg.ring_spacing_rad,
            )
            keep[failed] = count >= cfg.scan_min_neighbours
    return keep


# Azimuth bins per scan line in the scan-pattern test's buckets: 0.5 deg, a few columns of a
# spinning LiDAR, so a window (multiplier columns either side) reads a handful of buckets.
_SCAN_BINS = 720
# Buckets of the scan-pattern test at most (lines x bins): a cloud numbering its rings sparsely
# gets fewer, wider bins (the counts do not change, only the points read per window).
_SCAN_BUCKETS_MAX = 1 << 21


def _scan_neighbours(
    sensor: np.ndarray,
    ring: np.ndarray,
    azimuth: np.ndarray,
    rng: np.ndarray,
    z: np.ndarray,
    radius: np.ndarray,
    query: np.ndarray,
    ring_reach: int,
    ring_spacing_rad: float,
) -> np.ndarray:
    """(Q,) for each ``query`` point: other points of its LiDAR within ``ring_reach`` rings, within
    its angular width ``radius / range`` in azimuth (wrapping at +-pi), within its ``radius`` in
    range and at a height one beam spacing per ring could reach."""
    # Counted from 0 (a count depends only on which line a point is on and on ring differences).
    sensor = sensor - sensor.min()
    ring = ring - ring.min()
    n_rings = int(ring.max()) + 2 * ring_reach + 1
    if (int(sensor.max()) + 1) * n_rings > _SCAN_BUCKETS_MAX:
        raise MessageError(
            f"dror_keep_mask.scan_grid: expected at most {_SCAN_BUCKETS_MAX} scan lines (sensors x "
            f"rings), got sensors spanning {int(sensor.max()) + 1} and rings spanning {n_rings}"
        )
    line = sensor * n_rings + ring  # rings of one sensor are consecutive line numbers
    # Candidates farther in range than any query's radius cannot count: only the near pool is
    # bucketed (a margin keeps the bound safe from rounding).
    q_rng = rng[query]
    pool = np.flatnonzero(
        (rng <= q_rng.max() + 2.0 * radius[query].max() + 1e-6)
        & (rng >= q_rng.min() - 2.0 * radius[query].max() - 1e-6)
    )
    n_lines = int(line[pool].max()) + 1 if len(pool) else 1
    return scan_window_counts(
        pool,
        line,
        ring,
        np.ascontiguousarray(azimuth, dtype=np.float64),
        rng,
        np.ascontiguousarray(z, dtype=np.float64),
        radius,
        np.asarray(query, dtype=np.int64),
        ring_reach,
        math.tan(ring_spacing_rad),
        max(1, min(_SCAN_BINS, _SCAN_BUCKETS_MAX // n_lines)),
    )


def azimuth_step_from_times(t_offset_us: npt.ArrayLike) -> float:
    """A spinning LiDAR's horizontal resolution from one sweep's per-point firing times.

    Columns fire at equal intervals over the period, so the typical gap between distinct firing
    times is one column and the sweep spans one period: step = 2 pi * gap / period. Returns 0 for
    a sweep whose times do not show columns (fewer than two distinct times).
    """
    t = np.asarray(t_offset_us)
    # Distinct values, sorted: widening float32 to float64 is exact and one-to-one, so the float64
    # values tell the times apart (+0.0 for -0.0). Found by hashing in one pass (a sweep listed
    # ring by ring, as KITTI's, is not in time order: np.unique's sort of every point cost ~3-5 ms
    # on 120k points), then only the distinct values are sorted; the same values as np.unique.
    # Non-finite times (never in a validated sweep) go the sorting way.
    w = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
    first, finite = first_of_each_value(w)
    t = np.sort(w[first] + 0.0) if finite else np.unique(t if t.dtype == np.float32 else w + 0.0)
    t = t.astype(np.float64)
    if len(t) < 2:
        return 0.0
    gap = float(np.median(np.diff(t)))
    period = float(t[-1] - t[0]) + gap
    return 2.0 * math.pi * gap / period
