"""Scoring of LiDAR object detection against simulator ground truth (used by
``benchmarks/perception_quality.py`` and checked on hand-made cases in ``test_quality_scoring.py``).

Rules (stated once here, printed by the benchmark):

- **Visible**: a road user with at least ``min_returns`` LiDAR returns on it in the merged rig frame
  the pipeline received (all three LiDARs, after the pipeline's crop), per the per-point truth.
- **Hit**: a cluster whose box centre lies inside the object's true footprint (oriented rectangle at
  the frame's reference time) grown by ``margin_m`` plus the distance the object moves in one
  sweep (its returns were taken up to one period before the reference time; de-skewing undoes
  the shuttle's motion, not the object's). Each cluster is given to the nearest such
  footprint only; an object is found when at least one cluster is given to it (a car split in two
  fragments is found once, and neither fragment is false).
- **False object**: a cluster given to no road user whose points are mostly (> half) phantom
  returns: precipitation echoes or the ground surface (road, sidewalk, snow on the road). Clusters
  mostly on solid scenery (buildings, poles, signs, curb faces) or on a road user are real things
  the pipeline is meant to report, so they are not false.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from lastmile.sim.lidar_scene import PointLabel

PHANTOM_LABELS = (PointLabel.ROAD, PointLabel.SIDEWALK, PointLabel.SNOW, PointLabel.WEATHER_NOISE)


def footprint_distance_m(xy_m: npt.ArrayLike, boxes: npt.ArrayLike) -> np.ndarray:
    """(K, M) distance from each point to each oriented rectangle (0 inside).

    Args:
        xy_m: (K, 2) points.
        boxes: (M, 5) rectangles ``x_m y_m yaw_rad length_m width_m`` (centre, heading, full sizes).
    """
    p = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
    dx = p[:, None, 0] - b[None, :, 0]
    dy = p[:, None, 1] - b[None, :, 1]
    c, s = np.cos(b[:, 2]), np.sin(b[:, 2])
    along = np.abs(dx * c + dy * s) - b[:, 3] / 2.0
    across = np.abs(-dx * s + dy * c) - b[:, 4] / 2.0
    return np.hypot(np.maximum(along, 0.0), np.maximum(across, 0.0))


def match_clusters(
    cluster_xy_m: npt.ArrayLike, boxes: npt.ArrayLike, margin_m: float | npt.ArrayLike
) -> np.ndarray:
    """(K,) index of the object each cluster centre is given to (nearest footprint within
    ``margin_m``, a scalar or one per object), -1 for none."""
    d = footprint_distance_m(cluster_xy_m, boxes)
    k, m = d.shape
    if m == 0:
        return np.full(k, -1, dtype=np.int64)
    margin = np.broadcast_to(np.asarray(margin_m, dtype=np.float64), (m,))
    best = np.argmin(d, axis=1)
    return np.where(d[np.arange(k), best] <= margin[best], best, -1).astype(np.int64)


def objects_found(matched: npt.ArrayLike, n_objects: int) -> np.ndarray:
    """(M,) bool: at least one cluster was given to the object."""
    m = np.asarray(matched, dtype=np.int64)
    found = np.zeros(n_objects, dtype=bool)
    found[m[m >= 0]] = True
    return found


def false_clusters(
    matched: npt.ArrayLike, point_cluster: npt.ArrayLike, point_label: npt.ArrayLike
) -> np.ndarray:
    """(K,) bool: clusters given to no object whose points are mostly phantom returns.

    Args:
        matched: (K,) from :func:`match_clusters`.
        point_cluster: (P,) cluster row (0..K-1) of every clustered point (-1: not in a kept cluster).
        point_label: (P,) the true :class:`PointLabel` of every point.
    """
    m = np.asarray(matched, dtype=np.int64)
    pc = np.asarray(point_cluster, dtype=np.int64)
    lab = np.asarray(point_label)
    k = len(m)
    inside = pc >= 0
    total = np.bincount(pc[inside], minlength=k)
    phantom = np.bincount(pc[inside & np.isin(lab, PHANTOM_LABELS)], minlength=k)
    return (m < 0) & (2 * phantom > total)


def visible_objects(
    point_object_id: npt.ArrayLike, object_ids: npt.ArrayLike, min_returns: int
) -> np.ndarray:
    """(M,) bool: objects with at least ``min_returns`` points carrying their id."""
    return returns_per_object(point_object_id, object_ids) >= min_returns


def returns_per_object(point_object_id: npt.ArrayLike, object_ids: npt.ArrayLike) -> np.ndarray:
    """(M,) number of points carrying each object's id."""
    pid = np.asarray(point_object_id, dtype=np.int64)
    ids = np.asarray(object_ids, dtype=np.int64)
    uniq, counts = np.unique(pid[pid >= 0], return_counts=True)
    pos = np.clip(np.searchsorted(uniq, ids), 0, max(len(uniq) - 1, 0))
    if len(uniq) == 0:
        return np.zeros(len(ids), dtype=np.int64)
    return np.where(uniq[pos] == ids, counts[pos], 0).astype(np.int64)


def returns_above_ground(
    point_object_id: npt.ArrayLike,
    point_z_m: npt.ArrayLike,
    object_ids: npt.ArrayLike,
    object_ground_z_m: npt.ArrayLike,
    min_height_m: float,
) -> np.ndarray:
    """(M,) number of each object's returns more than ``min_height_m`` above the ground it stands on.

    A return a few centimetres above the ground (a goose's feet grazed by a low beam) is, to any
    LiDAR method, ground: range noise and curb-scale relief are of that size.
    """
    pid = np.asarray(point_object_id, dtype=np.int64)
    z = np.asarray(point_z_m, dtype=np.float64)
    ids = np.asarray(object_ids, dtype=np.int64)
    gz = np.asarray(object_ground_z_m, dtype=np.float64)
    order = np.argsort(ids)
    pos = np.clip(np.searchsorted(ids[order], pid), 0, max(len(ids) - 1, 0))
    known = (pid >= 0) & (len(ids) > 0)
    if len(ids):
        known &= ids[order][pos] == pid
    ground = np.where(known, gz[order][pos] if len(ids) else 0.0, np.inf)
    high = known & (z > ground + min_height_m)
    return returns_per_object(np.where(high, pid, -1), ids)
