"""What ``lastmile perceive`` writes: KITTI object labels and a Foxglove-viewable MCAP of each frame.

KITTI's object format puts boxes in the rectified camera frame. Files without a camera calibration
get the camera axes placed at the base origin: x_cam = -y_base (right), y_cam = -z_base (down),
z_cam = x_base (forward), the box's location at its bottom centre, ``rotation_y = -yaw - pi/2``
(KITTI's convention: 0 faces the camera's x axis). The image box is unknown (``-1 -1 -1 -1``), as are
truncation and occlusion (-1), alpha is -10 (KITTI's "not given"); the score is the 16th column, as
in KITTI's result files.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lastmile.core.object_class import ObjectClass
from lastmile.perception.lidar_detector import MergedObjects
from lastmile.perception.pipeline import LidarPipelineResult

KITTI_TYPE = {
    ObjectClass.CAR: "Car",
    ObjectClass.PEDESTRIAN: "Pedestrian",
    ObjectClass.CYCLIST: "Cyclist",
}
"""KITTI type of each object class the pipeline can report; any other class is ``Misc``."""

if TYPE_CHECKING:
    from foxglove.messages import Pose

POINT_CLASSES = ("ground", "weather_noise", "object", "other")
"""Values of the point cloud's ``class`` field in the MCAP (index = value)."""


def kitti_label_lines(objects: MergedObjects) -> list[str]:
    """One KITTI object line per object of a frame (base frame mapped to KITTI's camera axes): a
    cluster is ``Misc`` with its confidence (at least 0.5, as late fusion scores LiDAR-only objects),
    a learned detector's box has the detector's class and score."""
    c = objects.clusters
    score = np.where(objects.from_detector, objects.score, np.maximum(c.col("confidence"), 0.5))
    lines = []
    for k in range(len(c.table)):
        x, y = c.col("x_m")[k], c.col("y_m")[k]
        z_min, z_max = c.col("z_min_m")[k], c.col("z_max_m")[k]
        length, width = max(c.col("length_m")[k], 0.1), max(c.col("width_m")[k], 0.1)
        yaw = c.col("yaw_rad")[k]
        height = max(z_max - z_min, 0.1)
        ry = math.remainder(-yaw - math.pi / 2, 2 * math.pi)
        kind = KITTI_TYPE.get(ObjectClass(int(objects.class_id[k])), "Misc")
        lines.append(
            f"{kind} -1 -1 -10 -1 -1 -1 -1 {height:.2f} {width:.2f} {length:.2f} "
            f"{-y:.2f} {-z_min:.2f} {x:.2f} {ry:.2f} {score[k]:.4f}"
        )
    return lines


def point_classes(result: LidarPipelineResult) -> np.ndarray:
    """(N,) uint8 class of each cloud point (:data:`POINT_CLASSES`)."""
    cls = np.full(len(result.labels), 3, dtype=np.uint8)
    kept = np.isin(result.labels, result.clusters.labels)
    cls[kept] = 2
    cls[result.noise] = 1
    cls[result.ground] = 0
    return cls


_CLUSTER_COLOUR_RGBA = {"r": 1.0, "g": 0.6, "b": 0.1, "a": 0.6}
_DETECTOR_COLOUR_RGBA = {"r": 0.2, "g": 0.5, "b": 1.0, "a": 0.6}


class FoxgloveFrameWriter:
    """Writes each frame's cloud (with its point classes) and object boxes into one MCAP file.

    Topics: ``/lidar/points`` (``foxglove.PointCloud``: x y z intensity class, float32) and
    ``/perception/objects`` (``foxglove.SceneUpdate``: one cube per object), both in the frame
    ``base``. A private Foxglove context keeps these channels out of any other recording.
    """

    def __init__(self, path: Path) -> None:
        import foxglove
        from foxglove.channels import PointCloudChannel, SceneUpdateChannel

        self._ctx = foxglove.Context()
        self._writer = foxglove.open_mcap(path, allow_overwrite=True, context=self._ctx)
        self._points = PointCloudChannel("/lidar/points", context=self._ctx)
        self._objects = SceneUpdateChannel("/perception/objects", context=self._ctx)
        self._colours = {
            False: foxglove.messages.Color(**_CLUSTER_COLOUR_RGBA),
            True: foxglove.messages.Color(**_DETECTOR_COLOUR_RGBA),
        }

    def write(self, result: LidarPipelineResult, objects: MergedObjects, log_time_ns: int) -> None:
        """One frame's cloud and objects (clusters orange, a detector's boxes blue), logged (and
        stamped) at ``log_time_ns``."""
        from foxglove import messages as m

        stamp = m.Timestamp(sec=log_time_ns // 1_000_000_000, nsec=log_time_ns % 1_000_000_000)
        pts = result.cloud.points
        packed = np.empty((len(pts), 5), dtype="<f4")
        packed[:, :4] = pts[:, :4]
        packed[:, 4] = point_classes(result)
        f32 = m.PackedElementFieldNumericType.Float32
        fields = [
            m.PackedElementField(name=name, offset=4 * i, type=f32)
            for i, name in enumerate(("x", "y", "z", "intensity", "class"))
        ]
        self._points.log(
            m.PointCloud(
                timestamp=stamp,
                frame_id="base",
                pose=_pose(0.0, 0.0, 0.0, 0.0),
                point_stride=20,
                fields=fields,
                data=packed.tobytes(),
            ),
            log_time=log_time_ns,
        )
        c = objects.clusters
        cubes = []
        for k in range(len(c.table)):
            z_min, z_max = c.col("z_min_m")[k], c.col("z_max_m")[k]
            cubes.append(
                m.CubePrimitive(
                    pose=_pose(c.col("x_m")[k], c.col("y_m")[k], 0.5 * (z_min + z_max), c.col("yaw_rad")[k]),
                    size=m.Vector3(
                        x=max(c.col("length_m")[k], 0.1),
                        y=max(c.col("width_m")[k], 0.1),
                        z=max(z_max - z_min, 0.1),
                    ),
                    color=self._colours[bool(objects.from_detector[k])],
                )
            )
        entity = m.SceneEntity(timestamp=stamp, frame_id="base", id="objects", cubes=cubes)
        self._objects.log(m.SceneUpdate(entities=[entity]), log_time=log_time_ns)

    def close(self) -> None:
        self._writer.close()


def _pose(x: float, y: float, z: float, yaw: float) -> Pose:
    from foxglove import messages as m

    return m.Pose(
        position=m.Vector3(x=float(x), y=float(y), z=float(z)),
        orientation=m.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
    )
