"""Curb-side surface told from objects by height profile, reflectivity and the map's curb lines.

Two kinds of returns along every mapped curb stand out of the road plane and cluster like low
objects, although they are the road's edge:

- **the curb face and sidewalk edge**: a 0.10-0.20 m step clears the ground tolerance near the
  sensor; seen from a moving bus the visible stretch moves with it, so a tracker gives such a
  cluster the bus's own speed. A cluster whose top is at most ``max_top_m`` and whose centre lies
  within ``max_face_distance_m`` of a curb line is the curb (any intensity: a concrete face in
  clear weather is as dim as a goose);
- **snow lying along the curb**: ploughed snow covers the lane edge beside every curb, up to curb
  height and sloping down to the road. Where the curb stage models that curb (the shuttle's right
  one) its snow is boundary surface and never reaches the clustering; along the other curbs it
  clusters like a low object, reaching farther from the curb line than a face does. A cluster is
  such snow when all of: **low and flat** (top at most ``max_top_m``, points spanning at most
  ``max_span_m`` in height: a goose is 0.4 m tall, a pedestrian 1.75 m); **bright** (fresh snow
  reflects ~0.8 of a 905 nm beam against 0.1 for asphalt and 0.2-0.3 for cars, clothing and
  feathers; at the grazing incidence of a ground return it still returns more than a goose does
  head-on; aUToronto 6.2.2 uses intensity after clustering, as here); **on a curb line** (centre
  within ``max_curb_distance_m``: snow cover plus bank is ~1.1 m wide).

Clusters of either kind are dropped from the objects and their points reported. Nothing is
learned; the thresholds are physical (heights, reflectivities, widths) and listed below.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from lastmile.core.errors import ConfigError, MessageError
from lastmile.perception.cluster_geometry import ClusterSet
from lastmile.perception.map_curbs import sample_polylines

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class SnowSurfaceConfig:
    """Attributes:
    max_top_m: a snow-surface cluster's top (base frame, road at z = 0) is below this: curb height
        0.15 m plus range noise and a rough bank rim; a goose's top is at 0.4 m.
    max_span_m: ...and its points span at most this in height (the bank itself is <= 0.15 m).
    min_mean_intensity: ...and its mean intensity (0..255) is at least this. Intensity follows
        reflectivity x (0.3 + 0.7 cos incidence): snow (0.8) returns 60-80 at the grazing incidence
        of a flat surface a few metres to the side (40-50 beyond 15 m in falling snow); a goose
        (0.2) returns at most ~51 even head-on, so 52 never takes a goose. Cars (0.3) and
        pedestrians (0.25) can return more, but are neither low nor flat.
    max_curb_distance_m: ...and its centre lies this close to a mapped curb line (ploughed snow
        lies within 1.1 m of the curb: 0.5 m of lane cover plus the 0.6 m bank; plus margin).
    max_face_distance_m: a cluster no higher than ``max_top_m`` whose centre lies this close to a
        mapped curb line is the curb face or sidewalk edge, whatever its intensity or height span:
        the snow bank's 0.6 m toe plus 0.3 m of map error (a ring grazing the bank toe 0.65 m from
        the curb gave a 2-point cluster 15 m ahead in every sweep on a curve, which stopped the
        bus).
    sample_step_m: spacing at which the curb polylines are sampled for the distance test.
    """

    max_top_m: float = 0.3
    max_span_m: float = 0.15
    min_mean_intensity: float = 52.0
    max_curb_distance_m: float = 1.2
    max_face_distance_m: float = 0.9
    sample_step_m: float = 0.1

    def __post_init__(self) -> None:
        for name in (
            "max_top_m",
            "max_span_m",
            "min_mean_intensity",
            "max_curb_distance_m",
            "max_face_distance_m",
            "sample_step_m",
        ):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ConfigError(f"SnowSurfaceConfig.{name}: expected a positive number, got {v!r}")
        if self.min_mean_intensity > 255:
            raise ConfigError(
                f"SnowSurfaceConfig.min_mean_intensity: expected <= 255 (0..255 scale), got "
                f"{self.min_mean_intensity}"
            )


def curb_distance_m(
    curb_lines_xy_m: Sequence[npt.ArrayLike], xy_m: npt.ArrayLike, step_m: float
) -> FloatArray:
    """(N,) distance from (N, 2) points to the nearest of the curb polylines (inf without curbs).

    Raises:
        MessageError: a curb line that is not a finite (M >= 2, 2) polyline.
    """
    samples = sample_polylines(curb_lines_xy_m, step_m, "curb_lines_xy_m")
    q = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    if len(samples) == 0 or len(q) == 0:
        return np.full(len(q), np.inf)
    d, _ = cKDTree(samples).query(q, k=1)
    return np.asarray(d, dtype=np.float64)


def snow_surface_clusters(
    clusters: ClusterSet, curb_lines_xy_m: Sequence[npt.ArrayLike], config: SnowSurfaceConfig | None = None
) -> np.ndarray:
    """(K,) bool: clusters that are curb-side surface: a curb face or sidewalk edge (low, on a curb
    line), or snow lying along a curb (low, flat, bright, beside a curb line).

    Args:
        clusters: the pipeline's clusters (base frame).
        curb_lines_xy_m: the HD map's curb lines near the vehicle, each (M, 2) in the base frame
            (any side, any direction).
        config: thresholds.
    """
    cfg = config or SnowSurfaceConfig()
    if len(clusters) == 0 or len(curb_lines_xy_m) == 0:
        return np.zeros(len(clusters), dtype=bool)
    top = clusters.col("z_max_m")
    span = top - clusters.col("z_min_m")
    low = top <= cfg.max_top_m
    snow_like = low & (span <= cfg.max_span_m) & (clusters.col("mean_intensity") >= cfg.min_mean_intensity)
    out = np.zeros(len(clusters), dtype=bool)
    if low.any():
        xy = np.c_[clusters.col("x_m"), clusters.col("y_m")][low]
        dist = curb_distance_m(curb_lines_xy_m, xy, cfg.sample_step_m)
        reach = np.where(
            snow_like[low], max(cfg.max_curb_distance_m, cfg.max_face_distance_m), cfg.max_face_distance_m
        )
        out[np.flatnonzero(low)[dist <= reach]] = True
    return out


def drop_clusters(clusters: ClusterSet, drop: npt.ArrayLike) -> ClusterSet:
    """The cluster set without the rows where ``drop`` is True."""
    keep = ~np.asarray(drop, dtype=bool)
    if keep.shape != (len(clusters),):
        raise MessageError(f"drop_clusters: expected a ({len(clusters)},) mask, got {keep.shape}")
    return ClusterSet(
        table=clusters.table[keep],
        hull_xy=clusters.hull_xy[keep],
        hull_new=clusters.hull_new[keep],
        labels=clusters.labels[keep],
    )
