"""HD-map road regions as a mask over base-frame points, for map-aware ground and curb processing."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from lastmile.core.geometry import SE2
from lastmile.hdmap.drivable import DrivableRaster
from lastmile.hdmap.model import DRIVABLE_SUBTYPES, HDMap

RoadMask = Callable[[npt.NDArray[np.float64]], npt.NDArray[np.bool_]]
"""Maps (N, 2) base-frame x, y in metres to an (N,) bool: True where the HD map says road surface."""

# Crosswalks are road surface at road height even though no car "drives" them as a lane.
ROAD_SURFACE_SUBTYPES = DRIVABLE_SUBTYPES | {"crosswalk"}


class MapRoadRegion:
    """The HD map's road surface, rasterised once (0.25 m cells) in the map frame.

    Cells an outline crosses count as road: a road-region mask only chooses which ground model a
    point is fitted with, so a quarter-cell error at the edge is harmless, and the curb detector
    searches +/- its own band around the map curb anyway.
    """

    def __init__(self, hdmap: HDMap, cell_m: float = 0.25) -> None:
        polys = [ll.polygon() for ll in hdmap.lanelets.values() if ll.subtype in ROAD_SURFACE_SUBTYPES]
        self.raster = DrivableRaster(polys, cell_m=cell_m)

    def mask_for(self, map_from_base: SE2) -> RoadMask:
        """A :data:`RoadMask` for the vehicle at ``map_from_base``."""

        def mask(xy_base_m: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
            xy_map = map_from_base.apply_points(np.asarray(xy_base_m, dtype=np.float64))
            return self.raster.classify(xy_map) != DrivableRaster.OUTSIDE

        return mask
