"""Our messages to and from MCAP records: lossless JSON channels plus Foxglove views for display.

Every message is written once losslessly, so replay gets back an equal message:

- a ``LidarSweep`` as a ``foxglove.PointCloud`` (float32 columns: already lossless);
- everything else as JSON with schema name ``lastmile.<Class>``: dataclasses are tagged objects,
  arrays ``{"$array": base64, "dtype", "shape"}``, enums ``{"$enum": class, "value"}``, non-finite
  floats ``{"$float": "nan" | "inf" | "-inf"}`` (JSON has none); Python's float repr round-trips exactly.

Some messages also get a view for Foxglove (pose, transform, objects, path), which replay ignores.
Decoding only builds classes from the core registry below: a file cannot make us import anything.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import math
from collections.abc import Iterator
from enum import Enum
from typing import Any

import numpy as np

from lastmile.core import (
    geometry,
    objects,
    safety_messages,
    sensor_frames,
    traffic_light_messages,
    vehicle_messages,
)
from lastmile.core.errors import LastmileError
from lastmile.core.gnss_messages import GnssQuality
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.recorder import foxglove_schemas as fx


class RecordingError(LastmileError):
    """A black-box recording is unreadable, malformed or holds a message we cannot decode."""


def _registry() -> tuple[dict[str, type], dict[str, type[Enum]]]:
    classes: dict[str, type] = {}
    enums: dict[str, type[Enum]] = {"ObjectClass": ObjectClass, "GnssQuality": GnssQuality}
    for module in (
        geometry,
        objects,
        safety_messages,
        sensor_frames,
        traffic_light_messages,
        vehicle_messages,
    ):
        for name, value in vars(module).items():
            if not isinstance(value, type) or value.__module__ != module.__name__:
                continue
            if dataclasses.is_dataclass(value):
                classes[name] = value
            elif issubclass(value, Enum):
                enums[name] = value
    return classes, enums


CLASSES, ENUMS = _registry()

LIDAR_SCHEMA = "foxglove.PointCloud"


def _to_json(value: Any) -> Any:
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else {"$float": repr(value)}
    if isinstance(value, Enum):
        return {"$enum": type(value).__name__, "value": value.value}
    if isinstance(value, np.ndarray):
        arr = np.ascontiguousarray(value)
        return {
            "$array": base64.b64encode(arr.tobytes()).decode("ascii"),
            "dtype": arr.dtype.str,
            "shape": list(arr.shape),
        }
    if isinstance(value, np.generic):
        return _to_json(value.item())
    if isinstance(value, tuple | list):
        return [_to_json(v) for v in value]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        name = type(value).__name__
        if CLASSES.get(name) is not type(value):
            raise RecordingError(
                f"encode: expected a message class of lastmile.core, got {type(value).__qualname__}"
            )
        out = {"$type": name}
        for f in dataclasses.fields(value):
            out[f.name] = _to_json(getattr(value, f.name))
        return out
    raise RecordingError(f"encode: expected a message field value, got {type(value).__name__}")


def _from_json(value: Any) -> Any:
    if isinstance(value, list):
        return tuple(_from_json(v) for v in value)
    if not isinstance(value, dict):
        return value
    if "$float" in value:
        return float(value["$float"])
    if "$enum" in value:
        enum = ENUMS.get(value["$enum"])
        if enum is None:
            raise RecordingError(f"decode: expected a known enum, got {value['$enum']!r}")
        return enum(value["value"])
    if "$array" in value:
        raw = base64.b64decode(value["$array"])
        arr = np.frombuffer(raw, dtype=np.dtype(value["dtype"])).reshape(value["shape"]).copy()
        arr.setflags(write=False)
        return arr
    if "$type" in value:
        cls = CLASSES.get(value["$type"])
        if cls is None:
            raise RecordingError(f"decode: expected a lastmile.core message type, got {value['$type']!r}")
        kwargs = {k: _from_json(v) for k, v in value.items() if k != "$type"}
        try:
            return cls(**kwargs)
        except (TypeError, LastmileError) as exc:
            raise RecordingError(f"decode: {value['$type']} could not be rebuilt: {exc}") from None
    return {k: _from_json(v) for k, v in value.items()}


def encode_message(message: Any) -> bytes:
    """Lossless JSON of one core message."""
    return json.dumps(_to_json(message), separators=(",", ":"), allow_nan=False).encode()


def decode_message(schema_name: str, data: bytes) -> Any:
    """The core message of a lossless record (``lastmile.*`` or ``foxglove.PointCloud`` schema)."""
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise RecordingError(f"decode: expected JSON for schema {schema_name}, got {exc}") from None
    if schema_name == LIDAR_SCHEMA:
        return sensor_frames.LidarSweep(
            stamp=Stamp(fx.stamp_of(doc["timestamp"])),
            sensor_id=doc["frame_id"],
            points=fx.points_from_cloud(doc),
        )
    return _from_json(doc)


def schema_of(message: Any) -> tuple[str, bytes]:
    """The (schema name, schema bytes) of a message's lossless channel."""
    if isinstance(message, sensor_frames.LidarSweep):
        return LIDAR_SCHEMA, fx.SCHEMA_BYTES[LIDAR_SCHEMA]
    name = type(message).__name__
    doc = {
        "title": f"lastmile.{name}",
        "type": "object",
        "description": (type(message).__doc__ or "").strip().splitlines()[0]
        if type(message).__doc__
        else name,
        "properties": {"$type": {"const": name}},
    }
    return f"lastmile.{name}", json.dumps(doc).encode()


def lossless_payload(message: Any) -> bytes:
    if isinstance(message, sensor_frames.LidarSweep):
        doc = fx.point_cloud(message.stamp, message.sensor_id, sensor_frames.LIDAR_COLUMNS, message.points)
        return json.dumps(doc, separators=(",", ":")).encode()
    return encode_message(message)


_TRACK_RGBA = (0.95, 0.55, 0.1, 0.6)
_DETECTION_RGBA = (0.2, 0.6, 1.0, 0.5)


def foxglove_views(topic: str, message: Any) -> Iterator[tuple[str, str, bytes]]:
    """Extra (topic, Foxglove schema name, payload) records that make a message visible in Foxglove."""
    dumps = json.dumps
    if isinstance(message, vehicle_messages.LocalizationEstimate) and message.valid:
        p = message.map_from_base
        pose = fx.planar_pose(p.x_m, p.y_m, p.yaw_rad)
        yield (
            "/viz/pose",
            "foxglove.PoseInFrame",
            dumps({"timestamp": fx.time_of(message.stamp), "frame_id": fx.MAP_FRAME, "pose": pose}).encode(),
        )
        yield (
            "/tf",
            "foxglove.FrameTransform",
            dumps(
                {
                    "timestamp": fx.time_of(message.stamp),
                    "parent_frame_id": fx.MAP_FRAME,
                    "child_frame_id": fx.BASE_FRAME,
                    "translation": pose["position"],
                    "rotation": pose["orientation"],
                }
            ).encode(),
        )
    elif isinstance(message, objects.TrackedObjects | objects.DetectedObjects):
        cols = (
            objects.TRACK_COLUMNS
            if isinstance(message, objects.TrackedObjects)
            else objects.DETECTION_COLUMNS
        )
        ix = {c: cols.index(c) for c in ("x_m", "y_m", "yaw_rad", "length_m", "width_m")}
        frame = fx.MAP_FRAME if getattr(message, "frame", "map") == "map" else fx.BASE_FRAME
        ids = message.ids.tolist() if isinstance(message, objects.TrackedObjects) else range(len(message))
        rgba = _TRACK_RGBA if isinstance(message, objects.TrackedObjects) else _DETECTION_RGBA
        entities = [
            fx.entity(
                message.stamp,
                f"{topic}/{tid}",
                frame,
                cubes=[
                    fx.cube(
                        row[ix["x_m"]],
                        row[ix["y_m"]],
                        row[ix["yaw_rad"]],
                        max(row[ix["length_m"]], 0.3),
                        max(row[ix["width_m"]], 0.3),
                        rgba,
                    )
                ],
            )
            for tid, row in zip(ids, message.table.tolist(), strict=True)
        ]
        yield f"/viz{topic}", "foxglove.SceneUpdate", dumps({"deletions": [], "entities": entities}).encode()
    elif isinstance(message, vehicle_messages.Trajectory):
        pts = [{"x": float(x), "y": float(y), "z": 0.05} for x, y in message.points[:, :2].tolist()]
        line = {
            "type": 0,
            "pose": fx.planar_pose(0.0, 0.0, 0.0),
            "thickness": 0.15,
            "scale_invariant": False,
            "points": pts,
            "color": {"r": 0.1, "g": 0.9, "b": 0.3, "a": 1.0},
            "colors": [],
            "indices": [],
        }
        ent = fx.entity(message.stamp, "trajectory", fx.MAP_FRAME, lines=[line])
        yield f"/viz{topic}", "foxglove.SceneUpdate", dumps({"deletions": [], "entities": [ent]}).encode()
