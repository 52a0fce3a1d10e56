"""The HD map's curb lines as a nearest-neighbour index, to tell curb returns from low obstacles.

A curb face is a 0.10-0.20 m step: its returns clear the ground tolerance near the sensor and cluster
like a low object lying along the kerb. Seen from a moving bus the visible stretch moves with it, so a
tracker gives such a cluster the bus's own speed. A cluster that is low and lies on a mapped curb line
is the curb; anything taller (a goose is 0.4 m) or off the curb line stays an object.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from lastmile.core.errors import ConfigError, MessageError
from lastmile.hdmap.model import HDMap

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class CurbReturnConfig:
    """Attributes:
    max_height_m: a cluster whose top is below this (base frame, road at z = 0) can be a curb
        (curb 0.15 m plus a snow bank's rim and range noise).
    max_distance_m: ...if its centre lies this close to a mapped curb line: the snow bank's 0.6 m
        toe plus 0.3 m of map error (a ring grazing the bank toe 0.65 m from the curb gave a 2-point
        cluster 15 m ahead in every sweep on a curve, which stopped the bus).
    sample_step_m: spacing of the points the curb lines are sampled at.
    """

    max_height_m: float = 0.3
    max_distance_m: float = 0.9
    sample_step_m: float = 0.1

    def __post_init__(self) -> None:
        for name in ("max_height_m", "max_distance_m", "sample_step_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"CurbReturnConfig.{name}: expected a positive number, got {v}")


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
    """Every curb line of the map, sampled densely, in a KD-tree (map frame)."""

    def __init__(self, hdmap: HDMap, config: CurbReturnConfig | None = None) -> None:
        self.config = config or CurbReturnConfig()
        samples = sample_polylines([c.xy_m for c in hdmap.curbs], self.config.sample_step_m, "hdmap.curbs")
        self._tree = cKDTree(samples) if len(samples) else None

    def distance_m(self, xy_map_m: npt.ArrayLike) -> FloatArray:
        """(N,) distance from (N, 2) map-frame points to the nearest curb line (inf without curbs)."""
        xy = np.asarray(xy_map_m, dtype=np.float64).reshape(-1, 2)
        if self._tree is None or len(xy) == 0:
            return np.full(len(xy), np.inf)
        d, _ = self._tree.query(xy, k=1)
        return np.asarray(d, dtype=np.float64)

    def curb_returns(self, xy_map_m: npt.ArrayLike, z_max_m: npt.ArrayLike) -> np.ndarray:
        """(N,) bool: clusters (centres in the map frame, tops in the base frame) that are curb returns."""
        z = np.asarray(z_max_m, dtype=np.float64).reshape(-1)
        near = self.distance_m(xy_map_m) <= self.config.max_distance_m
        return near & (z < self.config.max_height_m)
