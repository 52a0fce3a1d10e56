"""HD-map road regions as a mask over base-frame points, for map-aware ground and curb processing."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from matplotlib.path import Path as MplPath

from lastmile.core.geometry import SE2
from lastmile.hdmap.drivable import DrivableRaster
from lastmile.hdmap.model import DRIVABLE_SUBTYPES, HDMap

RoadMask = Callable[[npt.NDArray[np.float64]], npt.NDArray[np.bool_]]
"""Maps (N, 2) base-frame x, y in metres to an (N,) bool: True where the HD map says road surface."""

# Crosswalks are road surface at road height even though no car "drives" them as a lane.
ROAD_SURFACE_SUBTYPES = DRIVABLE_SUBTYPES | {"crosswalk"}


class MapRoadRegion:
    """The HD map's road surface: a raster (0.25 m cells) in the map frame, exact at the edges.

    Points in cells no outline comes near are answered by the raster; points in cells an outline
    crosses (and their neighbours) by the exact polygon test. The edge matters: a curb is 0.15 m
    high and the ground tolerance near the bus 0.12 m, so a sidewalk strip called road (up to half
    a metre wide if edge cells counted as road) stands out of the road plane as a row of
    obstacles along every curb.
    """

    def __init__(self, hdmap: HDMap, cell_m: float = 0.25) -> None:
        polys = [ll.polygon() for ll in hdmap.lanelets.values() if ll.subtype in ROAD_SURFACE_SUBTYPES]
        self.raster = DrivableRaster(polys, cell_m=cell_m)
        self._paths = [MplPath(p) for p in polys]
        self._lo = np.array([p.min(axis=0) for p in polys]).reshape(-1, 2)
        self._hi = np.array([p.max(axis=0) for p in polys]).reshape(-1, 2)

    def contains(self, xy_map_m: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
        """(N,) bool: map-frame points on the road surface."""
        xy = np.asarray(xy_map_m, dtype=np.float64).reshape(-1, 2)
        verdict = self.raster.classify(xy)
        out = verdict == DrivableRaster.INSIDE
        edge = np.flatnonzero(verdict == DrivableRaster.EDGE)
        if len(edge):
            out[edge] = self._exact(xy[edge])
        return out

    def _exact(self, xy: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
        inside = np.zeros(len(xy), dtype=bool)
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        # Per axis, as below: the verdict of all(axis=1) without its reduction's cost.
        lo_b, hi_b = self._lo, self._hi
        near = np.flatnonzero(
            (lo_b[:, 0] <= hi[0]) & (lo_b[:, 1] <= hi[1]) & (hi_b[:, 0] >= lo[0]) & (hi_b[:, 1] >= lo[1])
        )
        x, y = xy[:, 0], xy[:, 1]
        for k in near.tolist():
            (lo_x, lo_y), (hi_x, hi_y) = self._lo[k], self._hi[k]
            # The box test per axis: the same verdict as all(axis=1), without its reduction's cost.
            sel = np.flatnonzero(~inside & (x >= lo_x) & (x <= hi_x) & (y >= lo_y) & (y <= hi_y))
            if len(sel):
                inside[sel] = self._paths[k].contains_points(xy[sel])
        return inside

    def mask_for(self, map_from_base: SE2) -> RoadMask:
        """A :data:`RoadMask` for the vehicle at ``map_from_base``."""

        def mask(xy_base_m: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
            return self.contains(map_from_base.apply_points(np.asarray(xy_base_m, dtype=np.float64)))

        return mask
