"""The 2-D occupancy map of the ``amcl`` mode: built from the point-cloud map, stored as ROS map_server
files (PGM image + YAML), and the planar scan a LiDAR cloud gives it.

NUS (IV-A) localizes with AMCL on a 2-D laser map. Here the map is the point-cloud map's points in a
height band above the road (``min_height_m`` to ``max_height_m``: walls, poles, parked vehicles; not the
road, not the canopy) projected onto a grid of ``resolution_m`` cells. A cell is occupied when a map
point falls in it; every other cell is written free (no ray casting: a cell no return reached is
indistinguishable from open space, which only matters for AMCL's random particles). The files follow
``map_server``'s format (``image``, ``resolution``, ``origin`` [x, y, yaw], ``negate``,
``occupied_thresh``, ``free_thresh``; occupied black 0, free white 254), so ROS tools and image viewers
open them. ``planar_scan`` is ``pointcloud_to_laserscan``: the nearest return in the same height band per
angular bin.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from lastmile.core.errors import MapError
from lastmile.localization.particle_filter import OccupancyGrid

OCCUPIED_PIXEL = 0
FREE_PIXEL = 254
MIN_HEIGHT_M = 0.5
"""Lowest return of the band, above the base frame's ground plane, m (above curbs and snow on the road)."""
MAX_HEIGHT_M = 2.5
"""Highest, m (a building's ground floor, poles, vehicles; below tree canopies that move with the wind)."""


def grid_from_points(
    points: np.ndarray,
    resolution_m: float = 0.1,
    min_height_m: float = MIN_HEIGHT_M,
    max_height_m: float = MAX_HEIGHT_M,
) -> OccupancyGrid:
    """The occupancy grid of map points (N, 3) in the height band, with a one-cell free border."""
    z = points[:, 2]
    band = points[(z >= min_height_m) & (z <= max_height_m), :2]
    if len(band) == 0:
        raise MapError(f"expected map points {min_height_m}-{max_height_m} m above the road, got none")
    lo = np.floor(band.min(axis=0) / resolution_m) * resolution_m - resolution_m
    cells = np.floor((band - lo) / resolution_m).astype(np.int64)
    w, h = int(cells[:, 0].max()) + 2, int(cells[:, 1].max()) + 2
    occupied = np.zeros((h, w), dtype=bool)
    occupied[cells[:, 1], cells[:, 0]] = True
    return OccupancyGrid(occupied=occupied, resolution_m=resolution_m, origin_xy=(float(lo[0]), float(lo[1])))


def write_grid(yaml_path: Path, grid: OccupancyGrid) -> Path:
    """Write ``grid`` as ``yaml_path`` and the PGM beside it (same stem); returns the PGM's path."""
    pgm = yaml_path.with_suffix(".pgm")
    occ = np.asarray(grid.occupied)
    # The image's first row is the map's top (largest y), as map_server reads it.
    img = np.where(occ[::-1], OCCUPIED_PIXEL, FREE_PIXEL).astype(np.uint8)
    h, w = img.shape
    pgm.write_bytes(f"P5\n{w} {h}\n255\n".encode() + img.tobytes())
    meta = {
        "image": pgm.name,
        "resolution": float(grid.resolution_m),
        "origin": [float(grid.origin_xy[0]), float(grid.origin_xy[1]), 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    yaml_path.write_text(yaml.safe_dump(meta, sort_keys=False))
    return pgm


def read_grid(yaml_path: Path | str) -> OccupancyGrid:
    """A map_server YAML + PGM (binary P5, 8 bit) as an :class:`OccupancyGrid`.

    Raises:
        MapError: a missing or malformed file (one line naming it and what was expected).
    """
    path = Path(yaml_path)
    if not path.is_file():
        raise MapError(f"{path}: expected an occupancy map (.yaml, map_server format), got no such file")
    try:
        meta = yaml.safe_load(path.read_text())
    except UnicodeDecodeError:
        raise MapError(f"{path}: expected map_server YAML text, got binary data (the .pgm image?)") from None
    except (OSError, yaml.YAMLError) as exc:
        raise MapError(
            f"{path}: expected map_server YAML, could not read it ({type(exc).__name__})"
        ) from None
    if not isinstance(meta, dict):
        raise MapError(f"{path}: expected a YAML mapping, got {type(meta).__name__}")
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise MapError(f"{path}: expected key '{key}', got keys {sorted(meta)}")
    resolution, origin = meta["resolution"], meta["origin"]
    if not isinstance(resolution, int | float) or not resolution > 0:
        raise MapError(f"{path}: expected a positive 'resolution', got {resolution!r}")
    if (
        not isinstance(origin, list)
        or len(origin) != 3
        or not all(isinstance(v, int | float) for v in origin)
    ):
        raise MapError(f"{path}: expected 'origin' [x, y, yaw], got {origin!r}")
    if origin[2] != 0:
        raise MapError(f"{path}: expected an unrotated map (origin yaw 0), got {origin[2]}")
    img = _read_pgm(path.parent / str(meta["image"]))
    thresh = float(meta.get("occupied_thresh", 0.65))
    occupancy = img.astype(float) / 255.0 if int(meta.get("negate", 0)) else (255.0 - img) / 255.0
    return OccupancyGrid(
        occupied=(occupancy > thresh)[::-1].copy(),
        resolution_m=float(resolution),
        origin_xy=(float(origin[0]), float(origin[1])),
    )


def _read_pgm(path: Path) -> np.ndarray:
    if not path.is_file():
        raise MapError(f"{path}: expected the occupancy map's image (PGM), got no such file")
    data = path.read_bytes()
    parts = data.split(maxsplit=4)
    if len(parts) < 5 or parts[0] != b"P5":
        raise MapError(f"{path}: expected a binary PGM (P5), got {data[:2]!r}")
    try:
        w, h, maxval = int(parts[1]), int(parts[2]), int(parts[3])
    except ValueError:
        raise MapError(f"{path}: expected a PGM header 'P5 W H MAXVAL', got {data[:32]!r}") from None
    pixels = parts[4]
    if maxval != 255 or len(pixels) < w * h:
        raise MapError(f"{path}: expected {w}x{h} 8-bit pixels, got {len(pixels)} bytes (max {maxval})")
    return np.frombuffer(pixels[: w * h], dtype=np.uint8).reshape(h, w)


def planar_scan(
    points_base: np.ndarray,
    bins: int = 360,
    min_height_m: float = MIN_HEIGHT_M,
    max_height_m: float = MAX_HEIGHT_M,
) -> tuple[np.ndarray, np.ndarray]:
    """(ranges, angles) of a cloud in the base frame: per angular bin the nearest return in the height
    band, at its own bearing (a bin's centre would misplace a 30 m return by up to 0.26 m at 1 degree),
    as a 2-D scanner at the base would see the map's band. Bins without a return are left out."""
    z = points_base[:, 2]
    pts = points_base[(z >= min_height_m) & (z <= max_height_m), :2]
    if len(pts) == 0:
        return np.zeros(0), np.zeros(0)
    r = np.hypot(pts[:, 0], pts[:, 1])
    bearing = np.arctan2(pts[:, 1], pts[:, 0])
    k = np.clip(np.floor((bearing + math.pi) / (2 * math.pi) * bins).astype(np.int64), 0, bins - 1)
    order = np.lexsort((r, k))
    first = order[np.flatnonzero(np.diff(k[order], prepend=-1))]
    return r[first], bearing[first]
