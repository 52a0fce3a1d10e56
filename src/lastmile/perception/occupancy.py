"""GEM's height-map occupancy grid (section V) and its obstacle-stop speed law, a simple baseline.

Cells of 0.25 m hold the spread (max z - min z) of their points; a cell is occupied when the spread
exceeds 0.07 m (pedestrian-sized objects with a VLP-16), after removing points above the shuttle.
The expected path comes from the steering angle through a bicycle model, widened to the body
plus a clearance; the nearest occupied cell on it within the look-ahead gives the speed
``v = d / 5 - 1`` (m/s, d in m): zero inside 5 m, i.e. full braking.
Limitations (GEM's own): flat-topped close obstacles (a car roof) and objects crossing cell borders
can be missed; it is a baseline, not the main detector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError, MessageError


@dataclass(frozen=True, slots=True, kw_only=True)
class HeightMapConfig:
    """Attributes:
    cell_m: grid cell size (GEM: 0.25 m).
    height_threshold_m: max - min spread that marks a cell occupied (GEM: 0.07 m).
    half_extent_m: the grid spans +/- this around the base origin.
    max_z_m: points above (over the shuttle's roof) are ignored.
    wheelbase_m: for the bicycle-model path.
    path_half_width_m: half the body width plus the side clearance.
    lookahead_m: path length checked (GEM: 15 m).
    """

    cell_m: float = 0.25
    height_threshold_m: float = 0.07
    half_extent_m: float = 20.0
    max_z_m: float = 3.0
    wheelbase_m: float = 2.6
    path_half_width_m: float = 1.3
    lookahead_m: float = 15.0

    def __post_init__(self) -> None:
        for name in (
            "cell_m",
            "height_threshold_m",
            "half_extent_m",
            "max_z_m",
            "wheelbase_m",
            "path_half_width_m",
            "lookahead_m",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"HeightMapConfig.{name}: expected a positive number, got {v}")


@dataclass(frozen=True, slots=True, kw_only=True)
class HeightMap:
    """Attributes:
    occupied: (G, G) bool, indexed [ix, iy]; cell centre x = -half + (ix + 0.5) * cell.
    spread_m: (G, G) float64 max - min height (0 where empty).
    observed: (G, G) bool, cells holding at least one point (None: not given). A cell without one is
        unknown, not free: NUS's cost map marks it so.
    """

    occupied: np.ndarray
    spread_m: np.ndarray
    cell_m: float
    half_extent_m: float
    observed: np.ndarray | None = None

    def cell_centres(self, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
        return np.stack(
            [-self.half_extent_m + (ix + 0.5) * self.cell_m, -self.half_extent_m + (iy + 0.5) * self.cell_m],
            1,
        )


def height_map(xyz_m: npt.ArrayLike, config: HeightMapConfig | None = None) -> HeightMap:
    """Build the grid from (N, 3) base-frame points."""
    cfg = config or HeightMapConfig()
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    g = math.ceil(2 * cfg.half_extent_m / cfg.cell_m)
    ij = np.floor((p[:, :2] + cfg.half_extent_m) / cfg.cell_m).astype(np.int64)
    ok = (ij >= 0).all(axis=1) & (ij < g).all(axis=1) & (p[:, 2] <= cfg.max_z_m)
    flat = ij[ok, 0] * g + ij[ok, 1]
    hi = np.full(g * g, -np.inf)
    lo = np.full(g * g, np.inf)
    np.maximum.at(hi, flat, p[ok, 2])
    np.minimum.at(lo, flat, p[ok, 2])
    spread = np.where(np.isfinite(hi), hi - lo, 0.0).reshape(g, g)
    return HeightMap(
        occupied=spread > cfg.height_threshold_m,
        spread_m=spread,
        cell_m=cfg.cell_m,
        half_extent_m=cfg.half_extent_m,
        observed=np.isfinite(hi).reshape(g, g),
    )


def nearest_obstacle_on_path_m(
    grid: HeightMap, steer_rad: float, config: HeightMapConfig | None = None, min_s_m: float = 0.0
) -> float:
    """Arc length (m) to the nearest occupied cell on the bicycle-model path; inf when clear.

    ``min_s_m``: cells nearer along the path are not counted (those beside the vehicle's own body,
    e.g. a curb it stands at, when the grid is centred on the rear axle)."""
    cfg = config or HeightMapConfig()
    if not math.isfinite(steer_rad):
        raise MessageError(f"nearest_obstacle_on_path_m: expected a finite steering angle, got {steer_rad}")
    ix, iy = np.nonzero(grid.occupied)
    if len(ix) == 0:
        return math.inf
    c = grid.cell_centres(ix, iy)
    curv = math.tan(steer_rad) / cfg.wheelbase_m
    if abs(curv) < 1e-6:
        s, lat = c[:, 0], c[:, 1]
    else:
        # Path: circle of radius R centred at (0, R); s along the arc, lateral = distance off it.
        R = 1.0 / curv
        dx, dy = c[:, 0], c[:, 1] - R
        rho = np.hypot(dx, dy)
        lat = np.abs(rho - abs(R))
        ang = np.arctan2(dx, -dy if R > 0 else dy)
        s = np.abs(R) * np.mod(ang, 2 * math.pi)
    on = (s >= min_s_m) & (s <= cfg.lookahead_m) & (lat <= cfg.path_half_width_m + grid.cell_m / 2)
    return float(s[on].min()) if on.any() else math.inf


def obstacle_stop_speed_mps(distance_m: float, cruise_speed_mps: float) -> float:
    """GEM's law v = d / 5 - 1 (m/s), clipped to [0, cruise]; 0 within 5 m, cruise when clear."""
    if not (math.isfinite(cruise_speed_mps) and cruise_speed_mps >= 0):
        raise MessageError(f"obstacle_stop_speed_mps: expected cruise >= 0, got {cruise_speed_mps}")
    if math.isnan(distance_m) or distance_m < 0:
        raise MessageError(f"obstacle_stop_speed_mps: expected distance >= 0, got {distance_m}")
    if math.isinf(distance_m):
        return cruise_speed_mps
    return float(min(max(distance_m / 5.0 - 1.0, 0.0), cruise_speed_mps))
