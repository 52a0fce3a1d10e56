"""The HD map's curb lines near the vehicle, in its base frame: the prior of the curb-side stage.

The pipeline's curb-side stage (:mod:`lastmile.perception.snow_surface`) tells curb faces and snow
lying along a curb from objects by where the map's curbs run; it needs every curb line near the
bus (any side, not only the one the curb detector models) in the base frame of the cloud.
:class:`MapCurbIndex` keeps each mapped curb as a polyline with vertices every
``vertex_step_m`` and cuts out the stretches within reach of a pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.hdmap.model import HDMap

FloatArray = npt.NDArray[np.float64]


def sample_polylines(lines: Sequence[npt.ArrayLike], step_m: float, what: str) -> FloatArray:
    """(K, 2) points every ``step_m`` or closer along each polyline, every vertex included.

    Raises:
        MessageError: a line that is not a finite (M >= 2, 2) polyline (``what[i]`` names it).
    """
    samples: list[FloatArray] = []
    for i, line in enumerate(lines):
        P = np.asarray(line, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 2 or len(P) < 2 or not np.isfinite(P).all():
            raise MessageError(f"{what}[{i}]: expected a finite (M >= 2, 2) polyline, got shape {P.shape}")
        seg = np.diff(P, axis=0)
        n = np.maximum(np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / step_m).astype(np.int64), 1)
        t = np.concatenate([np.arange(k) / k for k in n])
        start = np.repeat(np.arange(len(seg)), n)
        samples.append(P[start] + t[:, None] * seg[start])
        samples.append(P[-1:])
    return np.vstack(samples) if samples else np.zeros((0, 2))


class MapCurbIndex:
    """Every curb line of the map with vertices every ``vertex_step_m`` (map frame).

    Args:
        hdmap: the map.
        vertex_step_m: vertex spacing of the stored lines (the curb-side stage samples them
            more finely itself; 2 m keeps a curve's shape within a few centimetres).
    """

    def __init__(self, hdmap: HDMap, vertex_step_m: float = 2.0) -> None:
        if not (math.isfinite(vertex_step_m) and vertex_step_m > 0):
            raise ConfigError(f"MapCurbIndex.vertex_step_m: expected a positive number, got {vertex_step_m}")
        self.lines: tuple[FloatArray, ...] = tuple(
            np.asarray(c.sub(0.0, c.length_m, vertex_step_m), dtype=np.float64) for c in hdmap.curbs
        )
        # Each line's bounding box: a line whose box lies beyond the reach has no vertex within it, so
        # a frame looks only at the few lines around the shuttle, however large the map.
        self._lo = np.array([xy.min(axis=0) for xy in self.lines]).reshape(-1, 2)
        self._hi = np.array([xy.max(axis=0) for xy in self.lines]).reshape(-1, 2)

    def lines_near(self, map_from_base: SE2, reach_m: float = 45.0) -> list[FloatArray]:
        """The stretches of every curb line with vertices within ``reach_m`` of the base origin,
        each (M >= 2, 2) in the base frame (each stretch grown by one vertex at both ends, so the
        segments crossing the reach stay whole)."""
        to_base = map_from_base.inverse()
        out: list[FloatArray] = []
        x, y = map_from_base.x_m, map_from_base.y_m
        gap_x = np.maximum(np.maximum(self._lo[:, 0] - x, x - self._hi[:, 0]), 0.0)
        gap_y = np.maximum(np.maximum(self._lo[:, 1] - y, y - self._hi[:, 1]), 0.0)
        for k in np.flatnonzero(np.hypot(gap_x, gap_y) <= reach_m).tolist():
            xy = self.lines[k]
            near = np.hypot(xy[:, 0] - map_from_base.x_m, xy[:, 1] - map_from_base.y_m) <= reach_m
            edges = np.flatnonzero(np.diff(np.r_[0, near.astype(np.int8), 0]))
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                run = xy[max(a - 1, 0) : min(b + 1, len(xy))]
                if len(run) >= 2:
                    out.append(to_base.apply_points(run))
        return out
