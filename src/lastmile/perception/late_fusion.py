"""WATonoBus's late fusion (section III-A4, Fig. 6): radar-LiDAR first, then camera frustums by depth.

1. Radar-LiDAR association: radar objects (position and over-ground velocity, each in its radar's
   frame) are brought into the base frame and assigned one-to-one (Hungarian, scipy) to LiDAR
   clusters; the cost is the distance from the radar point to the cluster's oriented box (0 inside),
   gated at ``radar_gate_m``. An associated cluster takes the radar velocity.
2. Camera association: every fused object's 3D box is projected into each camera (K, [R|t]); in
   depth order, nearest first, an object claims the unclaimed camera box of highest IoU whose
   frustum holds the object's centre (IoU >= ``min_iou``). Nearer objects claim first, so an object
   hidden behind another cannot steal the box of the one in front.
3. Output: :class:`core.objects.DetectedObjects`, class from the camera box (UNKNOWN where no camera
   matched), velocity from radar (0 where none), in the base frame or, given ``map_from_base``, the
   map frame. With ``confirm_with_radar`` only radar-confirmed objects or camera-confirmed ones are
   kept (the paper's false-alarm removal in bad weather); by default LiDAR-only objects stay, since
   geese and other small things barely show on radar. Scores: 0.5 LiDAR only, 0.6 radar-confirmed,
   the camera detection's score when higher. A learned LiDAR detector's rows
   (:mod:`lastmile.perception.lidar_detector`) come with their class and score: a camera box that
   names a class replaces the detector's, one of class UNKNOWN leaves it.
4. Optionally NUS's pedestrian verification (its section III; ``pedestrian_verification``,
   :mod:`lastmile.perception.pedestrian_verification`) decides who is a pedestrian instead of step 2's
   boxes: a LiDAR cluster is one only when it is shaped like a standing person and a camera
   pedestrian box overlaps its projected box well enough; a pedestrian label step 2 gave any other
   cluster is withdrawn (UNKNOWN: NUS tracks unverified candidates as generic dynamic objects, which
   decision still avoids). Other classes are step 2's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2, wrap_angles_rad
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import DETECTION_COLUMNS, DetectedObjects
from lastmile.core.sensor_frames import CAMERA_BOX_COLUMNS, RADAR_COLUMNS, CameraDetections, RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.perception.camera_geometry import box_corners_3d, box_iou
from lastmile.perception.cluster_geometry import ClusterSet
from lastmile.perception.pedestrian_verification import PedestrianVerificationConfig, verify_pedestrians


@dataclass(frozen=True, slots=True, kw_only=True)
class LateFusionConfig:
    """Attributes:
    radar_gate_m: largest radar-to-box distance for an association.
    min_iou: smallest image IoU for a camera association.
    min_camera_score: camera boxes below this score are ignored.
    confirm_with_radar: drop objects confirmed by neither radar nor camera (bad-weather mode).
    keep_radar_only: also output radar objects no cluster explains (default off: radar ghosts).
    radar_only_size_m: footprint given to radar-only objects.
    pedestrian_verification: NUS's verification of LiDAR pedestrian candidates by the camera (None:
        WATonoBus's camera boxes name pedestrians like every other class).
    """

    radar_gate_m: float = 1.5
    min_iou: float = 0.2
    min_camera_score: float = 0.3
    confirm_with_radar: bool = False
    keep_radar_only: bool = False
    radar_only_size_m: float = 1.0
    pedestrian_verification: PedestrianVerificationConfig | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.radar_gate_m) and self.radar_gate_m > 0):
            raise ConfigError(f"LateFusionConfig.radar_gate_m: expected > 0, got {self.radar_gate_m}")
        if not (0 < self.min_iou <= 1 and 0 <= self.min_camera_score <= 1 and self.radar_only_size_m > 0):
            raise ConfigError(f"LateFusionConfig: expected min_iou in (0, 1], score in [0, 1], got {self}")


RADAR_CONFIRMED_SCORE = 0.6
"""Score of a fused object a radar confirmed and no camera box classified."""
UNCONFIRMED_SCORE = 0.5
"""Score of a LiDAR cluster neither a radar nor a camera confirmed."""


def radar_detections(frame: RadarFrame, map_from_radar: SE2, size_m: float = 1.0) -> DetectedObjects:
    """A radar frame's objects as the detections a radar-only tracker consumes (map frame).

    Radar object lists carry no class and no extent: each object is ``UNKNOWN``, a ``size_m`` square
    (the fusion's ``radar_only_size_m``) heading along its velocity, scored like a radar-confirmed
    object without a camera box (:data:`RADAR_CONFIRMED_SCORE`).
    """
    xyv = radar_in_base(frame, map_from_radar)
    out = np.zeros((len(xyv), len(DETECTION_COLUMNS)))
    out[:, 0:4] = xyv
    out[:, 4] = out[:, 5] = size_m
    out[:, 6] = np.arctan2(xyv[:, 3], xyv[:, 2])
    out[:, 7] = int(ObjectClass.UNKNOWN)
    out[:, 8] = RADAR_CONFIRMED_SCORE
    return DetectedObjects(stamp=frame.stamp, frame="map", source=f"radar_{frame.sensor_id}", table=out)


def radar_in_base(frame: RadarFrame, base_from_radar: SE2) -> np.ndarray:
    """(N, 4) x, y, vx, vy of a radar frame's objects in the base frame."""
    o = frame.objects
    c, s = math.cos(base_from_radar.yaw_rad), math.sin(base_from_radar.yaw_rad)
    i = {k: RADAR_COLUMNS.index(k) for k in ("x_m", "y_m", "vx_mps", "vy_mps")}
    xy = base_from_radar.apply_points(o[:, [i["x_m"], i["y_m"]]])
    vx = c * o[:, i["vx_mps"]] - s * o[:, i["vy_mps"]]
    vy = s * o[:, i["vx_mps"]] + c * o[:, i["vy_mps"]]
    return np.column_stack([xy, vx, vy])


def _box_distance(px: np.ndarray, py: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(R, K) distance from R points to K oriented boxes (rows x, y, ..., length, width, yaw)."""
    cx, cy, L, W, yaw = t[:, 0], t[:, 1], t[:, 4], t[:, 5], t[:, 6]
    dx, dy = px[:, None] - cx[None], py[:, None] - cy[None]
    c, s = np.cos(yaw), np.sin(yaw)
    u, v = c * dx + s * dy, -s * dx + c * dy
    ou = np.maximum(np.abs(u) - L / 2, 0.0)
    ov = np.maximum(np.abs(v) - W / 2, 0.0)
    return np.hypot(ou, ov)


@dataclass(frozen=True, slots=True, kw_only=True)
class FusedObjects:
    """:func:`fuse_objects` output: the detections and, per row, what confirmed them.

    Attributes:
        objects: the fused detections.
        radar_matched: (N,) bool, the row took a radar object's velocity.
        camera_matched: (N,) bool, the row took a camera box's class.
        z_min_m, z_max_m: (N,) vertical extent in the base frame (radar-only rows: 0 .. 1.5 m).
    """

    objects: DetectedObjects
    radar_matched: np.ndarray
    camera_matched: np.ndarray
    z_min_m: np.ndarray
    z_max_m: np.ndarray


def fuse(
    stamp: Stamp,
    clusters: ClusterSet,
    radar_frames: Sequence[RadarFrame] = (),
    base_from_radar: Mapping[str, SE2] | None = None,
    cameras: Sequence[PinholeCamera] = (),
    camera_detections: Sequence[CameraDetections] = (),
    map_from_base: SE2 | None = None,
    config: LateFusionConfig | None = None,
) -> DetectedObjects:
    """Fuse one cycle's LiDAR clusters, radar objects and camera boxes into 3D detections.

    Raises:
        MessageError: a radar without a mounting or camera detections without their camera.
    """
    return fuse_objects(
        stamp, clusters, radar_frames, base_from_radar, cameras, camera_detections, map_from_base, config
    ).objects


def fuse_objects(
    stamp: Stamp,
    clusters: ClusterSet,
    radar_frames: Sequence[RadarFrame] = (),
    base_from_radar: Mapping[str, SE2] | None = None,
    cameras: Sequence[PinholeCamera] = (),
    camera_detections: Sequence[CameraDetections] = (),
    map_from_base: SE2 | None = None,
    config: LateFusionConfig | None = None,
    lidar_class_id: np.ndarray | None = None,
    lidar_score: np.ndarray | None = None,
) -> FusedObjects:
    """:func:`fuse`, also saying which rows radar and camera confirmed (a tracker uses the Doppler).

    ``lidar_class_id`` and ``lidar_score`` ((K,) per cluster row) are a LiDAR detector's class and
    score (:mod:`lastmile.perception.lidar_detector`): a row keeps that class unless a camera box
    claims it, and its score is the highest of the detector's, radar's and camera's.
    """
    cfg = config or LateFusionConfig()
    mounts = base_from_radar or {}
    t = clusters.table
    n_l = len(t)
    # Fused object rows: x, y, z_min, z_max, length, width, yaw, vx, vy, radar_ok
    rows = np.zeros((n_l, 10))
    if n_l:
        rows[:, :7] = t[:, :7]
    radar = [radar_in_base(f, _mount(mounts, f.sensor_id)) for f in radar_frames]
    R = np.vstack(radar) if radar else np.zeros((0, 4))
    if len(R) and n_l:
        cost = _box_distance(R[:, 0], R[:, 1], t)
        big = 1e6
        ri, ci = linear_sum_assignment(np.where(cost <= cfg.radar_gate_m, cost, big))
        ok = cost[ri, ci] <= cfg.radar_gate_m
        ri, ci = ri[ok], ci[ok]
        rows[ci, 7:9] = R[ri, 2:4]
        rows[ci, 9] = 1.0
        used = np.zeros(len(R), dtype=bool)
        used[ri] = True
    else:
        used = np.zeros(len(R), dtype=bool)
    if cfg.keep_radar_only and (~used).any():
        extra = R[~used]
        add = np.zeros((len(extra), 10))
        add[:, 0:2] = extra[:, 0:2]
        add[:, 3] = 1.5
        add[:, 4] = add[:, 5] = cfg.radar_only_size_m
        add[:, 6] = np.arctan2(extra[:, 3], extra[:, 2])
        add[:, 7:9] = extra[:, 2:4]
        add[:, 9] = 1.0
        rows = np.vstack([rows, add])
    n = len(rows)
    cls = np.full(n, int(ObjectClass.UNKNOWN))
    score = np.where(rows[:, 9] > 0, RADAR_CONFIRMED_SCORE, UNCONFIRMED_SCORE)
    _apply_lidar_priors(n_l, lidar_class_id, lidar_score, cls, score)
    camera_ok = np.zeros(n, dtype=bool)
    by_id = {c.camera_id: c for c in cameras}
    for det in camera_detections:
        if det.camera_id not in by_id:
            raise MessageError(
                f"fuse: expected detections from a known camera {sorted(by_id)}, got {det.camera_id!r}"
            )
        _associate_camera(rows, by_id[det.camera_id], det, cfg, cls, score, camera_ok)
    if cfg.pedestrian_verification is not None:
        _nus_pedestrians(clusters, by_id, camera_detections, cfg.pedestrian_verification, cls, camera_ok)
    keep = np.ones(n, dtype=bool)
    if cfg.confirm_with_radar:
        keep = (rows[:, 9] > 0) | camera_ok
    out = np.zeros((int(keep.sum()), len(DETECTION_COLUMNS)))
    r = rows[keep]
    out[:, 0:2] = r[:, 0:2]
    out[:, 2:4] = r[:, 7:9]
    out[:, 4] = np.maximum(r[:, 4], 0.1)
    out[:, 5] = np.maximum(r[:, 5], 0.1)
    out[:, 6] = r[:, 6]
    out[:, 7] = cls[keep]
    out[:, 8] = score[keep]
    frame = "base"
    if map_from_base is not None:
        out[:, 0:2] = map_from_base.apply_points(out[:, 0:2])
        c, s = math.cos(map_from_base.yaw_rad), math.sin(map_from_base.yaw_rad)
        vx, vy = out[:, 2].copy(), out[:, 3].copy()
        out[:, 2], out[:, 3] = c * vx - s * vy, s * vx + c * vy
        out[:, 6] = wrap_angles_rad(out[:, 6] + map_from_base.yaw_rad)
        frame = "map"
    return FusedObjects(
        objects=DetectedObjects(stamp=stamp, frame=frame, source="fusion", table=out),
        radar_matched=r[:, 9] > 0,
        camera_matched=camera_ok[keep],
        z_min_m=r[:, 2].copy(),
        z_max_m=r[:, 3].copy(),
    )


def _nus_pedestrians(
    clusters: ClusterSet,
    cameras: Mapping[str, PinholeCamera],
    camera_detections: Sequence[CameraDetections],
    config: PedestrianVerificationConfig,
    cls: np.ndarray,
    camera_ok: np.ndarray,
) -> None:
    """NUS: pedestrians are the candidates some camera verifies; nobody else keeps that class."""
    verified = np.zeros(len(clusters.table), dtype=bool)
    for det in camera_detections:
        out = verify_pedestrians(clusters, cameras[det.camera_id], det, config)
        verified[out.rows[out.verified]] = True
    ped = int(ObjectClass.PEDESTRIAN)
    rows = np.arange(len(verified))
    cls[rows[(cls[: len(verified)] == ped) & ~verified]] = int(ObjectClass.UNKNOWN)
    cls[rows[verified]] = ped
    camera_ok[rows[verified]] = True


def _apply_lidar_priors(
    n_l: int, class_id: np.ndarray | None, prior: np.ndarray | None, cls: np.ndarray, score: np.ndarray
) -> None:
    for name, arr in (("lidar_class_id", class_id), ("lidar_score", prior)):
        if arr is not None and np.shape(arr) != (n_l,):
            raise MessageError(f"fuse: expected {name} of shape ({n_l},), got {np.shape(arr)}")
    if class_id is not None:
        cls[:n_l] = class_id
    if prior is not None:
        score[:n_l] = np.maximum(score[:n_l], prior)


def _mount(mounts: Mapping[str, SE2], sensor_id: str) -> SE2:
    if sensor_id not in mounts:
        raise MessageError(f"fuse: expected a mounting for radar {sensor_id!r}, got only {sorted(mounts)}")
    return mounts[sensor_id]


def _associate_camera(
    rows: np.ndarray,
    camera: PinholeCamera,
    det: CameraDetections,
    cfg: LateFusionConfig,
    cls: np.ndarray,
    score: np.ndarray,
    camera_ok: np.ndarray,
) -> None:
    si = CAMERA_BOX_COLUMNS.index("score")
    ci = CAMERA_BOX_COLUMNS.index("class_id")
    boxes = det.boxes[det.boxes[:, si] >= cfg.min_camera_score]
    if len(boxes) == 0 or len(rows) == 0:
        return
    claimed = np.zeros(len(boxes), dtype=bool)
    centres = np.column_stack([rows[:, 0], rows[:, 1], (rows[:, 2] + rows[:, 3]) / 2])
    depth = camera.to_camera(centres)[:, 2]
    uv, front = camera.pixels_from_base(centres)
    for k in np.argsort(depth):
        if not front[k] or camera_ok[k]:
            continue
        corners = box_corners_3d(
            rows[k, 0],
            rows[k, 1],
            rows[k, 2],
            rows[k, 3],
            max(rows[k, 4], 0.1),
            max(rows[k, 5], 0.1),
            rows[k, 6],
        )
        img = camera.project_box(corners)
        if img is None:
            continue
        u, v = uv[k]
        in_frustum = (boxes[:, 0] <= u) & (u <= boxes[:, 2]) & (boxes[:, 1] <= v) & (v <= boxes[:, 3])
        iou = box_iou(img[None, :], boxes[:, :4])[0]
        iou[claimed | ~in_frustum] = 0.0
        j = int(np.argmax(iou))
        if iou[j] >= cfg.min_iou:
            claimed[j] = True
            camera_ok[k] = True
            # A camera box that names no class leaves a LiDAR detector's class standing.
            if int(boxes[j, ci]) != int(ObjectClass.UNKNOWN) or cls[k] == int(ObjectClass.UNKNOWN):
                cls[k] = int(boxes[j, ci])
            score[k] = max(score[k], float(boxes[j, si]))
