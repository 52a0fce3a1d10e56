"""The point-cloud map on disk: a PCD file (x, y, z in the map frame, float64) and a JSON sidecar.

``lastmile map build`` writes it (:mod:`lastmile.runner.map_build_replay`); the ``scan_matching``
localization mode reads it. PCD is the Point Cloud Library's format: any PCD viewer (CloudCompare,
pcl_viewer, Foxglove) opens it. Coordinates are float64 so a map in a projected frame (UTM: 10^5-10^6 m)
keeps millimetres. The sidecar (``MAP.pcd.json``) says what the points are: the frame, the voxel size,
the source recording, the extent, how many frames went in and how well they registered.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.errors import MapError

MIN_MAP_POINTS = 100
"""Fewer points than this is not a map a scan can register to (the matcher's own minimum)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PointCloudMapInfo:
    """The sidecar of a point-cloud map.

    Attributes:
        frame: the frame of the points (``map``: the HD map's frame the stack localizes in).
        voxel_m: voxel size the map was downsampled to, m.
        source: the recording it was built from.
        points: number of points in the PCD file.
        extent_min_m, extent_max_m: (x, y, z) bounds of the points, m.
        frames_total: LiDAR rig frames in the recording.
        frames_used: rig frames placed in the map (one per ``keyframe_m`` of travel or turn).
        frames_registered: of those, the ones whose registration to the map so far was accepted and
            applied; the others were placed at the recorded pose as is.
        registration_rmse_p50_m, registration_rmse_p95_m: point-to-plane RMSE of the accepted
            registrations (median, 95th percentile), m; None if none.
        correction_p50_m, correction_max_m: how far registration moved the recorded poses, m.
        pose_source: what placed the frames (the recording's own localization, ``map -> base_link``).
        occupancy_map: the 2-D occupancy map written beside it for the ``amcl`` mode (map_server YAML).
    """

    frame: str
    voxel_m: float
    source: str
    points: int
    extent_min_m: tuple[float, float, float]
    extent_max_m: tuple[float, float, float]
    frames_total: int
    frames_used: int
    frames_registered: int
    registration_rmse_p50_m: float | None
    registration_rmse_p95_m: float | None
    correction_p50_m: float | None
    correction_max_m: float | None
    pose_source: str
    occupancy_map: str | None = None


def sidecar_path(pcd: Path) -> Path:
    """``MAP.pcd`` -> ``MAP.pcd.json``."""
    return pcd.with_name(pcd.name + ".json")


def write_point_cloud_map(path: Path, points: np.ndarray, info: PointCloudMapInfo) -> None:
    """Write ``points`` ((N, 3), map frame, m) as a binary PCD and ``info`` beside it."""
    import pypcd4

    xyz = np.ascontiguousarray(points, dtype=np.float64)
    cloud = pypcd4.PointCloud.from_points(xyz, ("x", "y", "z"), (np.float64, np.float64, np.float64))
    path.parent.mkdir(parents=True, exist_ok=True)
    cloud.save(path)
    sidecar_path(path).write_text(json.dumps(asdict(info), indent=2) + "\n")


def read_point_cloud_map(path: Path | str) -> np.ndarray:
    """The (N, 3) float64 points of a PCD map.

    Raises:
        MapError: a missing or unreadable file, no x/y/z fields, fewer than :data:`MIN_MAP_POINTS`
            points, or non-finite coordinates (one line, naming the file).
    """
    import pypcd4

    p = Path(path)
    if not p.is_file():
        raise MapError(f"{p}: expected a point-cloud map (.pcd), got no such file")
    try:
        cloud = pypcd4.PointCloud.from_path(p)
    except Exception as exc:  # pypcd4 raises pydantic, ValueError, struct errors...: one line for all
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MapError(f"{p}: expected a PCD point cloud, could not read it ({first})") from None
    missing = [f for f in ("x", "y", "z") if f not in cloud.fields]
    if missing:
        raise MapError(f"{p}: expected fields x, y, z, got {list(cloud.fields)}")
    xyz = np.asarray(cloud.numpy(("x", "y", "z")), dtype=np.float64).reshape(-1, 3)
    if xyz.shape[0] < MIN_MAP_POINTS:
        raise MapError(f"{p}: expected at least {MIN_MAP_POINTS} map points, got {xyz.shape[0]}")
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        raise MapError(f"{p}: expected finite coordinates, got NaN or inf at point {int(np.argmax(bad))}")
    return xyz


def read_sidecar(path: Path) -> dict[str, Any] | None:
    """The sidecar of a map as written (None when there is none)."""
    side = sidecar_path(path)
    if not side.is_file():
        return None
    try:
        data = json.loads(side.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise MapError(f"{side}: expected the map's JSON sidecar, could not read it ({exc})") from None
    return data if isinstance(data, dict) else None


def extent(points: np.ndarray) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(min, max) corners of ``points``, m."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    return (
        (float(lo[0]), float(lo[1]), float(lo[2])),
        (float(hi[0]), float(hi[1]), float(hi[2])),
    )


def percentile_or_none(values: list[float], q: float) -> float | None:
    """The ``q``-th percentile of ``values`` (None when empty), rounded to 0.1 mm."""
    if not values:
        return None
    v = float(np.percentile(np.asarray(values), q))
    return round(v, 4) if math.isfinite(v) else None
