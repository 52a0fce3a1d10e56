"""JSON schemas of the Foxglove message types the black box writes, and builders for their payloads.

Foxglove picks a panel from the schema name (``foxglove.PointCloud`` ...) with ``jsonschema`` encoding;
the schemas below list the fields Foxglove's published schemas define for these types.
"""

from __future__ import annotations

import base64
import json
import math
from typing import Any

import numpy as np

_NUM = {"type": "number"}
_INT = {"type": "integer", "minimum": 0}
_STR = {"type": "string"}


def _obj(title: str, **props: Any) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": props, "required": list(props)}


_TIME = _obj("time", sec=_INT, nsec={"type": "integer", "minimum": 0, "maximum": 999_999_999})
_DURATION = _obj(
    "duration", sec={"type": "integer"}, nsec={"type": "integer", "minimum": 0, "maximum": 999_999_999}
)
_VEC3 = _obj("foxglove.Vector3", x=_NUM, y=_NUM, z=_NUM)
_POINT3 = _obj("foxglove.Point3", x=_NUM, y=_NUM, z=_NUM)
_QUAT = _obj("foxglove.Quaternion", x=_NUM, y=_NUM, z=_NUM, w=_NUM)
_POSE = _obj("foxglove.Pose", position=_VEC3, orientation=_QUAT)
_COLOR = _obj("foxglove.Color", r=_NUM, g=_NUM, b=_NUM, a=_NUM)
_NUMERIC_TYPE = {
    "title": "foxglove.NumericType",
    "oneOf": [
        {"title": name, "const": i}
        for i, name in enumerate(
            ("UNKNOWN", "UINT8", "INT8", "UINT16", "INT16", "UINT32", "INT32", "FLOAT32", "FLOAT64")
        )
    ],
}
_FIELD = _obj("foxglove.PackedElementField", name=_STR, offset=_INT, type=_NUMERIC_TYPE)
_CUBE = _obj("foxglove.CubePrimitive", pose=_POSE, size=_VEC3, color=_COLOR)
_LINE = _obj(
    "foxglove.LinePrimitive",
    type={
        "title": "foxglove.LineType",
        "oneOf": [
            {"title": "LINE_STRIP", "const": 0},
            {"title": "LINE_LOOP", "const": 1},
            {"title": "LINE_LIST", "const": 2},
        ],
    },
    pose=_POSE,
    thickness=_NUM,
    scale_invariant={"type": "boolean"},
    points={"type": "array", "items": _POINT3},
    color=_COLOR,
    colors={"type": "array", "items": _COLOR},
    indices={"type": "array", "items": _INT},
)
_TEXT = _obj(
    "foxglove.TextPrimitive",
    pose=_POSE,
    billboard={"type": "boolean"},
    font_size=_NUM,
    scale_invariant={"type": "boolean"},
    color=_COLOR,
    text=_STR,
)
_KEY_VALUE = _obj("foxglove.KeyValuePair", key=_STR, value=_STR)
_ANY_ITEMS = {"type": "array", "items": {"type": "object"}}
_ENTITY = _obj(
    "foxglove.SceneEntity",
    timestamp=_TIME,
    frame_id=_STR,
    id=_STR,
    lifetime=_DURATION,
    frame_locked={"type": "boolean"},
    metadata={"type": "array", "items": _KEY_VALUE},
    arrows=_ANY_ITEMS,
    cubes={"type": "array", "items": _CUBE},
    spheres=_ANY_ITEMS,
    cylinders=_ANY_ITEMS,
    lines={"type": "array", "items": _LINE},
    triangles=_ANY_ITEMS,
    texts={"type": "array", "items": _TEXT},
    models=_ANY_ITEMS,
)
# Foxglove's schema requires every primitive list (empty when unused).
PRIMITIVE_LISTS = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")

SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.PointCloud": _obj(
        "foxglove.PointCloud",
        timestamp=_TIME,
        frame_id=_STR,
        pose=_POSE,
        point_stride=_INT,
        fields={"type": "array", "items": _FIELD},
        data={"type": "string", "contentEncoding": "base64"},
    ),
    "foxglove.PoseInFrame": _obj("foxglove.PoseInFrame", timestamp=_TIME, frame_id=_STR, pose=_POSE),
    "foxglove.FrameTransform": _obj(
        "foxglove.FrameTransform",
        timestamp=_TIME,
        parent_frame_id=_STR,
        child_frame_id=_STR,
        translation=_VEC3,
        rotation=_QUAT,
    ),
    "foxglove.SceneUpdate": _obj(
        "foxglove.SceneUpdate",
        deletions={"type": "array", "items": {"type": "object"}},
        entities={"type": "array", "items": _ENTITY},
    ),
    "foxglove.Log": _obj(
        "foxglove.Log",
        timestamp=_TIME,
        level={
            "title": "foxglove.LogLevel",
            "oneOf": [
                {"title": n, "const": i}
                for i, n in enumerate(("UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL"))
            ],
        },
        message=_STR,
        name=_STR,
        file=_STR,
        line=_INT,
    ),
}
for _name, _schema in SCHEMAS.items():
    _schema["$comment"] = "Field set of Foxglove's published schema of the same name (jsonschema encoding)."

SCHEMA_BYTES = {name: json.dumps(schema, separators=(",", ":")).encode() for name, schema in SCHEMAS.items()}

MAP_FRAME = "map"
BASE_FRAME = "base_link"

# PointCloud field types (foxglove.NumericType).
FLOAT32 = 7


def time_of(stamp_us: int) -> dict[str, int]:
    """Foxglove time from integer microseconds."""
    sec, rem = divmod(int(stamp_us), 1_000_000)
    return {"sec": sec, "nsec": rem * 1000}


def stamp_of(time: dict[str, int]) -> int:
    """Integer microseconds from a Foxglove time written by :func:`time_of` (exact)."""
    return int(time["sec"]) * 1_000_000 + int(time["nsec"]) // 1000


def yaw_quaternion(yaw_rad: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw_rad / 2.0), "w": math.cos(yaw_rad / 2.0)}


def planar_pose(x_m: float, y_m: float, yaw_rad: float, z_m: float = 0.0) -> dict[str, Any]:
    return {"position": {"x": x_m, "y": y_m, "z": z_m}, "orientation": yaw_quaternion(yaw_rad)}


def point_cloud(stamp_us: int, frame_id: str, columns: tuple[str, ...], points: np.ndarray) -> dict[str, Any]:
    """A ``foxglove.PointCloud`` of an (N, k) float32 array whose columns are named ``columns``.

    The first three columns are renamed x, y, z (Foxglove needs those names for positions).
    """
    pts = np.ascontiguousarray(points, dtype="<f4")
    names = ["x", "y", "z", *columns[3:]]
    return {
        "timestamp": time_of(stamp_us),
        "frame_id": frame_id,
        "pose": planar_pose(0.0, 0.0, 0.0),
        "point_stride": 4 * pts.shape[1],
        "fields": [{"name": n, "offset": 4 * i, "type": FLOAT32} for i, n in enumerate(names)],
        "data": base64.b64encode(pts.tobytes()).decode("ascii"),
    }


def points_from_cloud(msg: dict[str, Any]) -> np.ndarray:
    """The (N, k) float32 array of a cloud written by :func:`point_cloud`."""
    k = len(msg["fields"])
    raw = base64.b64decode(msg["data"])
    return np.frombuffer(raw, dtype="<f4").reshape(-1, k).astype(np.float32)


def cube(
    x_m: float, y_m: float, yaw_rad: float, length_m: float, width_m: float, rgba: tuple[float, ...]
) -> dict[str, Any]:
    r, g, b, a = rgba
    return {
        "pose": planar_pose(x_m, y_m, yaw_rad, 0.8),
        "size": {"x": length_m, "y": width_m, "z": 1.6},
        "color": {"r": r, "g": g, "b": b, "a": a},
    }


def entity(stamp_us: int, entity_id: str, frame_id: str = MAP_FRAME, **primitives: Any) -> dict[str, Any]:
    out: dict[str, Any] = {
        "timestamp": time_of(stamp_us),
        "frame_id": frame_id,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 200_000_000},
        "frame_locked": False,
        "metadata": [],
    }
    for name in PRIMITIVE_LISTS:
        out[name] = list(primitives.pop(name, []))
    if primitives:
        raise ValueError(f"entity: expected primitives among {PRIMITIVE_LISTS}, got {sorted(primitives)}")
    return out
