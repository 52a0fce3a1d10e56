"""The ground the simulated LiDAR sees: road level, raised sidewalks, and the distance to the curb.

A 0.1 m raster built once from the HD map answers, for any map point, whether it lies on the road
surface (any lanelet or parking area, at z = 0) or off it (sidewalk and verges, raised by the curb
height), and how far a road point is from the nearest mapped curb (for snow banks). Look-ups are
vectorised integer indexing: tens of thousands of ground hits per sweep cost about a millisecond.

Known limit: everything off the lanelets is raised, also where the map draws no curb, so the gap
between a junction's parting turn lanes that no lanelet covers stands as a curb-high island.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import FloatArray
from lastmile.hdmap.model import HDMap

RESOLUTION_M = 0.1
CURB_BAND_M = 4.0  # curb distances are stored up to this far from a curb (the widest snow bank)
_DIST_STEP_M = CURB_BAND_M / 250.0  # 1.6 cm per uint8 level; 255 means "farther than the band"
_FAR = 255


class GroundRaster:
    """Road mask and curb distance on a regular grid covering the map's road network.

    Attributes:
        x0_m, y0_m: map coordinates of the lower-left corner of cell (0, 0).
        road: (H, W) bool, True where the surface is road level (z = 0).
        curb_code: (H, W) uint8, distance to the nearest curb in steps of ``CURB_BAND_M / 250``
            (255: farther than ``CURB_BAND_M``); built on first use.
    """

    def __init__(self, hdmap: HDMap, margin_m: float = 3.0) -> None:
        polys = [hdmap.polygon_of(lid) for lid in hdmap.lanelets]
        polys += [np.asarray(a.polygon, dtype=float) for a in hdmap.areas if a.subtype == "parking"]
        lo = np.min([p.min(axis=0) for p in polys], axis=0) - margin_m
        hi = np.max([p.max(axis=0) for p in polys], axis=0) + margin_m
        self.x0_m, self.y0_m = float(lo[0]), float(lo[1])
        self.width = math.ceil((hi[0] - lo[0]) / RESOLUTION_M)
        self.height = math.ceil((hi[1] - lo[1]) / RESOLUTION_M)
        self.road = np.zeros((self.height, self.width), dtype=bool)
        for poly in polys:
            self._fill(poly)
        self._curbs = [np.asarray(c.xy_m, dtype=float) for c in hdmap.curbs]
        self._curb_code: np.ndarray | None = None

    def _fill(self, poly: FloatArray) -> None:
        """Even-odd scan-line fill of one polygon at cell centres (a difference array per row)."""
        xs = (poly[:, 0] - self.x0_m) / RESOLUTION_M - 0.5
        ys = (poly[:, 1] - self.y0_m) / RESOLUTION_M - 0.5
        r0, r1 = max(0, math.ceil(ys.min())), min(self.height - 1, math.floor(ys.max()))
        if r1 < r0:
            return
        rows = np.arange(r0, r1 + 1, dtype=float)[:, None]
        xa, ya = xs[None, :], ys[None, :]
        xb, yb = np.roll(xs, -1)[None, :], np.roll(ys, -1)[None, :]
        crosses = (ya <= rows) != (yb <= rows)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = np.where(crosses, xa + (rows - ya) * (xb - xa) / (yb - ya), np.inf)
        xc.sort(axis=1)
        n_cross = crosses.sum(axis=1)
        c0, c1 = max(0, math.floor(xs.min())), min(self.width - 1, math.ceil(xs.max()))
        diff = np.zeros((len(rows), c1 - c0 + 2), dtype=np.int16)
        for k in range(0, int(n_cross.max()) - 1, 2):
            ok = n_cross > k + 1
            a = np.clip(np.ceil(xc[ok, k]) - c0, 0, c1 - c0 + 1).astype(np.int64)
            b = np.clip(np.floor(xc[ok, k + 1]) - c0 + 1, 0, c1 - c0 + 1).astype(np.int64)
            rr = np.flatnonzero(ok)
            np.add.at(diff, (rr, a), 1)
            np.add.at(diff, (rr, b), -1)
        inside = np.cumsum(diff, axis=1)[:, :-1] > 0
        self.road[r0 : r1 + 1, c0 : c1 + 1] |= inside

    def cells(self, x_m: FloatArray, y_m: FloatArray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Row and column of each point and whether it falls on the raster at all."""
        col = np.floor((x_m - self.x0_m) / RESOLUTION_M).astype(np.int64)
        row = np.floor((y_m - self.y0_m) / RESOLUTION_M).astype(np.int64)
        ok = (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        return np.where(ok, row, 0), np.where(ok, col, 0), ok

    def is_road(self, x_m: FloatArray, y_m: FloatArray) -> np.ndarray:
        """(N,) bool: road-level surface (False off the raster: everything there is raised verge)."""
        col = np.floor((x_m - self.x0_m) / RESOLUTION_M).astype(np.int64)
        row = np.floor((y_m - self.y0_m) / RESOLUTION_M).astype(np.int64)
        ok = (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        # One look-up in the flattened raster (a view): the cells :meth:`cells` gives, without
        # its two selections and the two-axis gather.
        return np.take(self.road.reshape(-1), np.where(ok, row * self.width + col, 0)) & ok

    @property
    def curb_code(self) -> np.ndarray:
        if self._curb_code is None:
            self._curb_code = self._build_curb_code()
        return self._curb_code

    def curb_distance_m(self, x_m: FloatArray, y_m: FloatArray) -> np.ndarray:
        """(N,) distance to the nearest mapped curb (inf beyond ``CURB_BAND_M``), 1.6 cm steps."""
        row, col, ok = self.cells(x_m, y_m)
        code = np.where(ok, self.curb_code[row, col], _FAR)
        return np.where(code == _FAR, np.inf, code * _DIST_STEP_M)

    def _build_curb_code(self) -> np.ndarray:
        """Exact point-to-segment distance for every cell within the band of every curb segment."""
        code = np.full((self.height, self.width), _FAR, dtype=np.uint8)
        band = CURB_BAND_M
        for xy in self._curbs:
            for p, q in itertools.pairwise(xy):
                lo = np.minimum(p, q) - band
                hi = np.maximum(p, q) + band
                c0 = max(0, int((lo[0] - self.x0_m) / RESOLUTION_M))
                c1 = min(self.width, int((hi[0] - self.x0_m) / RESOLUTION_M) + 1)
                r0 = max(0, int((lo[1] - self.y0_m) / RESOLUTION_M))
                r1 = min(self.height, int((hi[1] - self.y0_m) / RESOLUTION_M) + 1)
                if c1 <= c0 or r1 <= r0:
                    continue
                cx = self.x0_m + (np.arange(c0, c1) + 0.5) * RESOLUTION_M
                cy = self.y0_m + (np.arange(r0, r1) + 0.5) * RESOLUTION_M
                e = q - p
                ee = max(float(e @ e), 1e-12)
                dx = cx[None, :] - p[0]
                dy = cy[:, None] - p[1]
                u = np.clip((dx * e[0] + dy * e[1]) / ee, 0.0, 1.0)
                dist = np.hypot(dx - u * e[0], dy - u * e[1])
                levels = np.where(dist < band, np.floor(dist / _DIST_STEP_M), _FAR).astype(np.uint8)
                np.minimum(code[r0:r1, c0:c1], levels, out=code[r0:r1, c0:c1])
        return code


def check_bank(bank_width_m: float, cover_m: float) -> None:
    """Snow-bank widths must fit the stored curb band."""
    for name, value in (("snow_bank_width_m", bank_width_m), ("snow_cover_lane_m", cover_m)):
        if not (math.isfinite(value) and value >= 0.0):
            raise ConfigError(f"LidarWeather.{name}: expected a finite number >= 0, got {value}")
    if bank_width_m + cover_m > CURB_BAND_M:
        raise ConfigError(
            f"LidarWeather: expected snow_bank_width_m + snow_cover_lane_m <= {CURB_BAND_M} m, got "
            f"{bank_width_m} + {cover_m}"
        )


def bank_height_m(
    dist_m: np.ndarray, curb_height_m: float, bank_width_m: float, cover_m: float
) -> np.ndarray:
    """Height of ploughed snow at a road point ``dist_m`` from the curb.

    Flat at curb height over ``cover_m`` of the lane (snow covering part of the lane), then a linear
    slope down to the road over ``bank_width_m``: the step at the curb is gone.
    """
    if bank_width_m <= 0.0 and cover_m <= 0.0:
        return np.zeros_like(dist_m)
    slope = np.clip((dist_m - cover_m) / max(bank_width_m, 1e-6), 0.0, 1.0)
    return np.where(np.isfinite(dist_m), curb_height_m * (1.0 - slope), 0.0)
