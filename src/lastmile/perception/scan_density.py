"""How much surface one return of each LiDAR stands for: its angular cell, column x ring spacing.

A rig mixes units of very different density: the front 32-ring unit samples 0.2 deg columns and
0.33 deg rings near the horizon, a 16-ring blind-spot unit 0.4 deg columns and 3.3 deg rings, about
20 times less densely. The cluster size filter's expected point count (``min_points_at_1m / r**2``)
is the dense unit's; a car end that only a blind-spot unit sees past the bus returns a short
vertical row of 3-4 points, which is as much evidence of a surface as 60-80 of the dense unit's.
Each return is weighted by its unit's angular cell relative to the densest unit of the frame, so
the filter asks every unit for the same surface, not the same number of points.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def ring_spacing_from_points(points: npt.ArrayLike, sample_every: int = 8) -> float:
    """A spinning LiDAR's typical vertical spacing of adjacent rings (rad) from one sweep.

    Args:
        points: (N, >= 5) sweep points in the sensor frame (``x y z intensity ring ...``), the
            unit mounted level.
        sample_every: every k-th point is used (each ring's elevation is the mean of its points).

    Returns:
        The median elevation step between consecutive rings that returned, 0 with fewer than two.
    """
    p = np.asarray(points)[::sample_every]
    if len(p) == 0:
        return 0.0
    x, y, z = (p[:, i].astype(np.float64) for i in range(3))
    ring = p[:, 4].astype(np.int64)
    elev = np.arctan2(z, np.hypot(x, y))
    if ring.min() < 0:
        return 0.0
    # Every return of a ring lies on that beam's cone: its mean elevation is the beam's.
    count = np.bincount(ring)
    rings = np.flatnonzero(count)
    if len(rings) < 2:
        return 0.0
    per_ring = np.bincount(ring, weights=elev)[rings] / count[rings]
    # Per ring number step: rings that returned nothing in a sweep leave a gap of several.
    step = np.diff(np.sort(per_ring)) / np.maximum(np.diff(rings), 1)
    return float(np.median(np.abs(step)))


def return_weights(azimuth_step_rad: npt.ArrayLike, ring_spacing_rad: npt.ArrayLike) -> np.ndarray:
    """(S,) weight of one return of each unit: its angular cell over the densest unit's (>= 1).

    Units whose spacing is unknown (0: too few returns to tell) get weight 1.
    """
    h = np.asarray(azimuth_step_rad, dtype=np.float64).reshape(-1)
    v = np.asarray(ring_spacing_rad, dtype=np.float64).reshape(-1)
    cell = h * v
    known = cell > 0
    if not known.any():
        return np.ones(len(cell))
    w = np.ones(len(cell))
    w[known] = np.maximum(cell[known] / cell[known].min(), 1.0)
    return w
