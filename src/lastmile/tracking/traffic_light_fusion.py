"""Traffic-light fusion (aUToronto 6.4.1): expected lights from the map, projected, associated with 2D boxes.

Per camera frame: (1) the map lights the camera should see (in range, in front of it, lenses facing
it, box inside the image); (2) their 3D housings projected to image boxes through the pinhole model of
:mod:`lastmile.core.camera_model`; (3) a one-to-one association of projected boxes and detected boxes
by the Hungarian method on centre distance (gated) plus a box-similarity term (1 - IoU).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.geometry import SE2
from lastmile.core.traffic_light_messages import MapTrafficLight

_NO_PAIR = 1e9  # cost of a gated-out pair; finite so linear_sum_assignment always has a solution


@dataclass(frozen=True, slots=True)
class ProjectedLights:
    """Map lights a camera should see in one frame.

    Attributes:
        indices: (M,) int64 indices into the tracker's light list.
        boxes: (M, 4) float64 projected housing boxes ``x1_px, y1_px, x2_px, y2_px``.
    """

    indices: np.ndarray
    boxes: np.ndarray


def light_positions(lights: tuple[MapTrafficLight, ...]) -> np.ndarray:
    """(N, 6) float64 per light: x_m, y_m, z_m, facing_rad, width_m, height_m."""
    return np.array(
        [[lt.x_m, lt.y_m, lt.z_m, lt.facing_rad, lt.width_m, lt.height_m] for lt in lights], dtype=np.float64
    ).reshape(-1, 6)


def project_lights(
    camera: PinholeCamera,
    lights: np.ndarray,
    map_from_base: SE2,
    max_range_m: float,
    max_view_angle_rad: float,
    min_depth_m: float = 1.0,
) -> ProjectedLights:
    """The lights ``camera`` should see from ``map_from_base``, and their image boxes.

    The pose is planar (the base on the road, z up); the housing is projected as a fronto-parallel
    rectangle of its width and height at its centre's depth, which is what a detector's box measures.

    Args:
        camera: the pinhole model and its mounting on the vehicle.
        lights: (N, 6) from :func:`light_positions`.
        map_from_base: the ego pose in the map frame.
        max_range_m: lights farther from the camera than this are not expected (too small to detect).
        max_view_angle_rad: lights whose lenses point more than this away from the camera are not
            expected (seen from the side or from behind a signal head shows no lit bulb).
        min_depth_m: lights closer than this along the optical axis are not expected.
    """
    if lights.shape[0] == 0:
        return ProjectedLights(np.zeros(0, dtype=np.int64), np.zeros((0, 4)))
    base_from_map = map_from_base.inverse()
    xy_base = base_from_map.apply_points(lights[:, :2])
    pts_base = np.column_stack([xy_base, lights[:, 2]])
    pts_cam = camera.to_camera(pts_base)
    depth = pts_cam[:, 2]
    # Camera centre in the map frame, for range and the lens-facing test.
    cam_x, cam_y = map_from_base.apply(camera.x_m, camera.y_m)
    dx, dy = cam_x - lights[:, 0], cam_y - lights[:, 1]
    dz = camera.z_m - lights[:, 2]
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    horiz = np.hypot(dx, dy)
    cos_view = (np.cos(lights[:, 3]) * dx + np.sin(lights[:, 3]) * dy) / np.maximum(horiz, 1e-9)
    ok = (depth > min_depth_m) & (dist <= max_range_m) & (cos_view >= math.cos(max_view_angle_rad))
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return ProjectedLights(np.zeros(0, dtype=np.int64), np.zeros((0, 4)))
    centre = camera.pixels_from_camera(pts_cam[idx])
    half_w = 0.5 * camera.fx_px * lights[idx, 4] / depth[idx]
    half_h = 0.5 * camera.fy_px * lights[idx, 5] / depth[idx]
    boxes = np.column_stack(
        [centre[:, 0] - half_w, centre[:, 1] - half_h, centre[:, 0] + half_w, centre[:, 1] + half_h]
    )
    # Expected only when the whole housing is in the image: a cut-off head is not reliably detected.
    inside = (
        (boxes[:, 0] >= 0)
        & (boxes[:, 1] >= 0)
        & (boxes[:, 2] <= camera.width_px)
        & (boxes[:, 3] <= camera.height_px)
    )
    return ProjectedLights(idx[inside].astype(np.int64), boxes[inside])


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M, K) IoU of image boxes a (M, 4) and b (K, 4), ``x1, y1, x2, y2``."""
    ix = np.clip(
        np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0.0, None
    )
    iy = np.clip(
        np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0.0, None
    )
    inter = ix * iy
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return np.asarray(inter / np.maximum(area_a[:, None] + area_b[None, :] - inter, 1e-12))


def associate(
    projected: np.ndarray, detected: np.ndarray, gate_px: float, iou_weight: float
) -> list[tuple[int, int]]:
    """Optimal one-to-one pairs (projected row, detected row) of image boxes.

    Cost of a pair: centre distance / ``gate_px`` + ``iou_weight`` * (1 - IoU); pairs whose centres are
    farther apart than ``gate_px`` are never made. Hungarian method (SciPy).

    Args:
        projected: (M, 4) boxes projected from the map.
        detected: (K, 4) detected boxes.
        gate_px: largest centre distance of an associated pair (pixels).
        iou_weight: weight of the box-dissimilarity term (dimensionless, >= 0).
    """
    if projected.shape[0] == 0 or detected.shape[0] == 0:
        return []
    cp = 0.5 * (projected[:, :2] + projected[:, 2:])
    cd = 0.5 * (detected[:, :2] + detected[:, 2:])
    dist = np.linalg.norm(cp[:, None, :] - cd[None, :, :], axis=2)
    cost = dist / gate_px + iou_weight * (1.0 - box_iou(projected, detected))
    gated = dist > gate_px
    cost[gated] = _NO_PAIR
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if not gated[r, c]]
