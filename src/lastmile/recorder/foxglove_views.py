"""What makes a recording visible in Foxglove: our messages as Foxglove's standard schemas (``foxglove-sdk``).

Each recorded message may add views on other channels, built with the ``foxglove.messages`` classes and
encoded as protobuf with the schemas the SDK ships (never a schema of ours): the ego pose
(``PoseInFrame``), the transform tree (``FrameTransforms`` on ``/tf``: map -> base_link -> every sensor at
its true mount), sensor data in their own frames (``PointCloud``), tracks and detections (``SceneUpdate``
cubes with an id and a class), the planned path, the route and the HD map (``SceneUpdate`` lines), the
behaviour state and the safety level (``Log``), camera detections (``ImageAnnotations``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from foxglove import messages as fm
from scipy.spatial.transform import Rotation

from lastmile.core import frame_kinds, objects, safety_messages, sensor_frames, vehicle_messages
from lastmile.core.object_class import ObjectClass
from lastmile.core.traffic_light_messages import LightState, TrafficLightDetections

MAP_FRAME = "map"
BASE_FRAME = "base_link"
TF_TOPIC = "/tf"
POSE_TOPIC = "/pose"
MAP_TOPIC = "/map"
ROUTE_TOPIC = "/route"
LOG_TOPIC = "/log"

_Box = tuple[tuple[float, ...], tuple[float, ...], str]
"""An image box (u0, v0, u1, v1), its colour (r, g, b) and its label."""

View = tuple[str, Any]
"""(topic, a ``foxglove.messages`` object)."""

_F32 = fm.PackedElementFieldNumericType.Float32
_CLASS_RGBA = {
    ObjectClass.UNKNOWN: (0.7, 0.7, 0.7),
    ObjectClass.CAR: (0.95, 0.55, 0.1),
    ObjectClass.PEDESTRIAN: (0.9, 0.15, 0.15),
    ObjectClass.CYCLIST: (0.8, 0.2, 0.8),
    ObjectClass.ANIMAL: (0.55, 0.35, 0.1),
}
_LIGHT_RGB = {"red": (0.9, 0.1, 0.1), "yellow": (0.95, 0.8, 0.1), "green": (0.1, 0.8, 0.2)}
_LOG_LEVEL = {
    safety_messages.FailSafeLevel.NONE: fm.LogLevel.Info,
    safety_messages.FailSafeLevel.SPEED_LIMIT: fm.LogLevel.Warning,
    safety_messages.FailSafeLevel.TAKEOVER_REQUEST: fm.LogLevel.Warning,
    safety_messages.FailSafeLevel.MINIMAL_RISK_MANOEUVRE: fm.LogLevel.Error,
    safety_messages.FailSafeLevel.EMERGENCY_STOP: fm.LogLevel.Error,
}


def timestamp(stamp_us: int) -> fm.Timestamp:
    """Foxglove time from integer microseconds (exact; negative stamps clamp to 0: the type is unsigned)."""
    sec, rem = divmod(max(int(stamp_us), 0), 1_000_000)
    return fm.Timestamp(sec=sec, nsec=rem * 1000)


def stamp_us_of(ts: Any) -> int:
    """Integer microseconds of a Foxglove timestamp (a decoded protobuf ``Timestamp``)."""
    return int(ts.seconds) * 1_000_000 + int(ts.nanos) // 1000


def _color(rgb: Sequence[float], a: float = 1.0) -> fm.Color:
    return fm.Color(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=a)


def _quat(yaw_rad: float) -> fm.Quaternion:
    return fm.Quaternion(x=0.0, y=0.0, z=math.sin(yaw_rad / 2.0), w=math.cos(yaw_rad / 2.0))


def planar_pose(x_m: float, y_m: float, yaw_rad: float, z_m: float = 0.0) -> fm.Pose:
    return fm.Pose(position=fm.Vector3(x=float(x_m), y=float(y_m), z=float(z_m)), orientation=_quat(yaw_rad))


def _transform(stamp_us: int, parent: str, child: str, matrix: np.ndarray) -> fm.FrameTransform:
    qx, qy, qz, qw = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    t = matrix[:3, 3]
    return fm.FrameTransform(
        timestamp=timestamp(stamp_us),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=fm.Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
        rotation=fm.Quaternion(x=float(qx), y=float(qy), z=float(qz), w=float(qw)),
    )


def planar_matrix(x_m: float, y_m: float, yaw_rad: float, z_m: float = 0.0) -> np.ndarray:
    """(4, 4) transform of a level pose."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = (x_m, y_m, z_m)
    return m


def sensor_frame_id(frame: sensor_frames.SensorFrame) -> str | None:
    """The transform-tree frame a sensor frame's data are in: the sensor's own name (``lidar_front``,
    ``radar_rear``, ``camera_front``); traffic-light cameras are ``light_camera_<id>``."""
    if isinstance(
        frame, sensor_frames.LidarSweep | sensor_frames.RadarFrame | sensor_frames.CameraDetections
    ):
        return frame_kinds.sensor_name(frame)
    camera_id = getattr(frame, "camera_id", None)
    return f"light_camera_{camera_id}" if camera_id is not None else None


def point_cloud(stamp_us: int, frame_id: str, names: Sequence[str], points: np.ndarray) -> fm.PointCloud:
    """A ``PointCloud`` of an (N, k) array, every column float32 (the first three are named x, y, z)."""
    pts = np.ascontiguousarray(points, dtype="<f4")
    fields = [fm.PackedElementField(name=n, offset=4 * i, type=_F32) for i, n in enumerate(names)]
    return fm.PointCloud(
        timestamp=timestamp(stamp_us),
        frame_id=frame_id,
        pose=planar_pose(0.0, 0.0, 0.0),
        point_stride=4 * pts.shape[1],
        fields=fields,
        data=pts.tobytes(),
    )


LIDAR_FIELD_NAMES = ("x", "y", "z", *sensor_frames.LIDAR_COLUMNS[3:])
RADAR_FIELD_NAMES = ("x", "y", *sensor_frames.RADAR_COLUMNS[2:], "z")


def _line(points_xy: np.ndarray, rgb: Sequence[float], thickness_m: float, z_m: float = 0.05) -> Any:
    pts = [fm.Point3(x=float(x), y=float(y), z=z_m) for x, y in np.asarray(points_xy)[:, :2].tolist()]
    return fm.LinePrimitive(
        type=fm.LinePrimitiveLineType.LineStrip,
        pose=planar_pose(0.0, 0.0, 0.0),
        thickness=thickness_m,
        points=pts,
        color=_color(rgb),
    )


def _entity(stamp_us: int, entity_id: str, frame_id: str, lifetime_s: float, **kw: Any) -> fm.SceneEntity:
    sec = int(lifetime_s)
    return fm.SceneEntity(
        timestamp=timestamp(stamp_us),
        frame_id=frame_id,
        id=entity_id,
        lifetime=fm.Duration(sec=sec, nsec=round((lifetime_s - sec) * 1e9)),
        **kw,
    )


def object_boxes(topic: str, message: objects.TrackedObjects | objects.DetectedObjects) -> fm.SceneUpdate:
    """One entity per object: a cube, a text label and metadata id, class, speed.

    A track is labelled ``<class> #<id>``; a detection (which has no id) ``<class> <score>`` with its
    score and source in the metadata, and an entity id unique to its source (``<topic>/<source>/<row>``),
    so the front and rear radars' detections of one cycle do not replace each other in a viewer.
    """
    tracked = isinstance(message, objects.TrackedObjects)
    cols = objects.TRACK_COLUMNS if tracked else objects.DETECTION_COLUMNS
    ix = {c: cols.index(c) for c in ("x_m", "y_m", "vx_mps", "vy_mps", "yaw_rad", "length_m", "width_m")}
    cls_ix = cols.index("class_id")
    frame = MAP_FRAME if getattr(message, "frame", "map") == "map" else BASE_FRAME
    ids: list[int] = (
        message.ids.tolist()
        if isinstance(message, objects.TrackedObjects)
        else list(range(len(message.table)))
    )
    prefix = topic if tracked else f"{topic}/{getattr(message, 'source', '')}"
    score_ix = None if tracked else cols.index("score")
    entities = []
    for oid, row in zip(ids, message.table.tolist(), strict=True):
        try:
            cls = ObjectClass(int(row[cls_ix]))
        except ValueError:
            cls = ObjectClass.UNKNOWN
        x, y, yaw = row[ix["x_m"]], row[ix["y_m"]], row[ix["yaw_rad"]]
        speed = math.hypot(row[ix["vx_mps"]], row[ix["vy_mps"]])
        metadata = [
            fm.KeyValuePair(key="id", value=str(oid)),
            fm.KeyValuePair(key="class", value=cls.name.lower()),
            fm.KeyValuePair(key="speed_mps", value=f"{speed:.2f}"),
        ]
        if score_ix is None:
            label = f"{cls.name.lower()} #{oid}"
        else:
            label = f"{cls.name.lower()} {row[score_ix]:.2f}"
            metadata.append(fm.KeyValuePair(key="score", value=f"{row[score_ix]:.3f}"))
            metadata.append(fm.KeyValuePair(key="source", value=str(getattr(message, "source", ""))))
        entities.append(
            _entity(
                message.stamp,
                f"{prefix}/{oid}",
                frame,
                0.25,
                metadata=metadata,
                cubes=[
                    fm.CubePrimitive(
                        pose=planar_pose(x, y, yaw, 0.8),
                        size=fm.Vector3(
                            x=max(row[ix["length_m"]], 0.3), y=max(row[ix["width_m"]], 0.3), z=1.6
                        ),
                        color=_color(_CLASS_RGBA[cls], 0.6 if tracked else 0.35),
                    )
                ],
                texts=[
                    fm.TextPrimitive(
                        pose=planar_pose(x, y, 0.0, 2.0),
                        billboard=True,
                        font_size=12.0,
                        scale_invariant=True,
                        color=_color((1.0, 1.0, 1.0)),
                        text=label,
                    )
                ],
            )
        )
    return fm.SceneUpdate(entities=entities)


def camera_annotations(message: sensor_frames.CameraDetections) -> fm.ImageAnnotations:
    """The detector's 2D boxes as closed outlines, each with its class and score."""
    col = {c: i for i, c in enumerate(sensor_frames.CAMERA_BOX_COLUMNS)}
    boxes: list[_Box] = []
    for row in message.boxes.tolist():
        try:
            cls = ObjectClass(int(row[col["class_id"]]))
        except ValueError:
            cls = ObjectClass.UNKNOWN
        corners = tuple(row[col[c]] for c in ("u_min_px", "v_min_px", "u_max_px", "v_max_px"))
        boxes.append((corners, _CLASS_RGBA[cls], f"{cls.name.lower()} {row[col['score']]:.2f}"))
    return _annotations(message.stamp, boxes)


def light_annotations(message: TrafficLightDetections) -> fm.ImageAnnotations:
    """The traffic-light detector's boxes, each with the state it read and its score."""
    boxes: list[_Box] = []
    for box, state, score in zip(
        message.boxes.tolist(), message.states.tolist(), message.scores.tolist(), strict=True
    ):
        name = LightState(state).name.lower()
        boxes.append((tuple(box), _LIGHT_RGB.get(name, (0.7, 0.7, 0.7)), f"{name} {score:.2f}"))
    return _annotations(message.stamp, boxes)


def _annotations(stamp_us: int, boxes: Sequence[_Box]) -> fm.ImageAnnotations:
    ts = timestamp(stamp_us)
    outlines, texts = [], []
    for (u0, v0, u1, v1), rgb, label in boxes:
        outlines.append(
            fm.PointsAnnotation(
                timestamp=ts,
                type=fm.PointsAnnotationType.LineLoop,
                points=[fm.Point2(x=u, y=v) for u, v in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))],
                outline_color=_color(rgb),
                thickness=2.0,
            )
        )
        texts.append(
            fm.TextAnnotation(
                timestamp=ts,
                position=fm.Point2(x=u0, y=max(v0 - 4.0, 0.0)),
                text=label,
                font_size=12.0,
                text_color=_color(rgb),
                background_color=_color((0.0, 0.0, 0.0), 0.5),
            )
        )
    return fm.ImageAnnotations(points=outlines, texts=texts)


def log(stamp_us: int, level: Any, name: str, text: str) -> fm.Log:
    return fm.Log(timestamp=timestamp(stamp_us), level=level, message=text, name=name)


@dataclass(slots=True)
class ViewBuilder:
    """Builds the views of one file's messages in log-time order (stateful: logs state changes once).

    Attributes:
        sensor_mounts: (4, 4) base_from_sensor of every sensor by frame id, published on every ``/tf``.
        map_lines: HD-map polylines (lane boundaries, stop lines, crosswalks; (N, 2) map frame).
        route: the service route's centre line ((N, 2) map frame), or None.
        map_radius_m: map lines with a vertex this close to the window's poses are written.
    """

    sensor_mounts: Mapping[str, np.ndarray]
    map_lines: Sequence[np.ndarray] = ()
    route: np.ndarray | None = None
    map_radius_m: float = 150.0
    _state: str = ""
    _level: Any = None
    _pose: tuple[float, float, float] | None = None
    _static: list[fm.FrameTransform] = field(default_factory=list)

    def opening(self, t0_us: int, poses_xy: np.ndarray) -> Iterator[View]:
        """The views a file starts with: the sensor mounts, the map around ``poses_xy``, the route."""
        self._static = [
            _transform(t0_us, BASE_FRAME, fid, m) for fid, m in sorted(self.sensor_mounts.items())
        ]
        yield TF_TOPIC, fm.FrameTransforms(transforms=list(self._static))
        if len(poses_xy) and self.map_lines:
            lo = poses_xy.min(axis=0) - self.map_radius_m
            hi = poses_xy.max(axis=0) + self.map_radius_m
            near = [
                ln
                for ln in self.map_lines
                if len(ln) >= 2 and np.any(np.all((ln >= lo) & (ln <= hi), axis=1))
            ]
            lines = [_line(ln, (0.55, 0.55, 0.6), 0.1, 0.0) for ln in near]
            yield MAP_TOPIC, fm.SceneUpdate(entities=[_entity(t0_us, "hd_map", MAP_FRAME, 0.0, lines=lines)])
        if self.route is not None and len(self.route) >= 2:
            line = _line(self.route, (0.2, 0.5, 1.0), 0.3, 0.02)
            yield (
                ROUTE_TOPIC,
                fm.SceneUpdate(entities=[_entity(t0_us, "route", MAP_FRAME, 0.0, lines=[line])]),
            )

    def views(self, log_us: int, topic: str, message: Any) -> Iterator[View]:
        """The views of one recorded message (none for most)."""
        if isinstance(message, vehicle_messages.LocalizationEstimate):
            if message.valid:
                yield from self._pose_views(message)
        elif isinstance(message, sensor_frames.RadarFrame):
            pts = np.zeros((len(message.objects), len(RADAR_FIELD_NAMES)), dtype=np.float32)
            pts[:, :-1] = message.objects
            yield (
                f"/viz{topic}",
                point_cloud(message.stamp, f"radar_{message.sensor_id}", RADAR_FIELD_NAMES, pts),
            )
        elif isinstance(message, objects.TrackedObjects | objects.DetectedObjects):
            yield f"/viz{topic}", object_boxes(topic, message)
        elif isinstance(message, vehicle_messages.Trajectory):
            if len(message.points) >= 2:
                line = _line(message.points, (0.1, 0.9, 0.3), 0.2)
                ent = _entity(message.stamp, "planned_path", MAP_FRAME, 0.5, lines=[line])
                yield f"/viz{topic}", fm.SceneUpdate(entities=[ent])
        elif isinstance(message, sensor_frames.CameraDetections):
            yield f"/viz{topic}", camera_annotations(message)
        elif isinstance(message, TrafficLightDetections):
            yield f"/viz{topic}", light_annotations(message)
        elif isinstance(message, vehicle_messages.BehaviourDecision):
            state = f"{message.state.value}: {message.reason}"
            if state != self._state:
                self._state = state
                yield LOG_TOPIC, log(log_us, fm.LogLevel.Info, "behaviour", state)
        elif isinstance(message, safety_messages.SafetyDirective):
            yield from self._safety_log(log_us, message)

    def _pose_views(self, est: vehicle_messages.LocalizationEstimate) -> Iterator[View]:
        p = est.map_from_base
        yield (
            POSE_TOPIC,
            fm.PoseInFrame(
                timestamp=timestamp(est.stamp), frame_id=MAP_FRAME, pose=planar_pose(p.x_m, p.y_m, p.yaw_rad)
            ),
        )
        ego = _transform(est.stamp, MAP_FRAME, BASE_FRAME, planar_matrix(p.x_m, p.y_m, p.yaw_rad))
        # The mounts ride along on every /tf, so a viewer that seeks into the middle still resolves them.
        yield TF_TOPIC, fm.FrameTransforms(transforms=[ego, *self._static])

    def _safety_log(self, log_us: int, directive: safety_messages.SafetyDirective) -> Iterator[View]:
        if directive.level == self._level:
            return
        self._level = directive.level
        level = _LOG_LEVEL[directive.level]
        text = (
            f"safety level {directive.level.name}, MRM {directive.mrm.name}: {'; '.join(directive.reasons)}"
        )
        yield LOG_TOPIC, log(log_us, level, "safety", text)
