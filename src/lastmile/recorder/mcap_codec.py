"""Our messages to and from MCAP records: lossless JSON channels plus Foxglove views for display.

Every message is written once losslessly, so replay gets back an equal message:

- a ``LidarSweep`` as a ``foxglove.PointCloud`` (protobuf, float32 columns: already lossless);
- everything else as JSON with schema name ``lastmile.<Class>`` (documented: ``record_schemas.py``):
  dataclasses are tagged objects,
  arrays ``{"$array": base64, "dtype", "shape"}``, enums ``{"$enum": class, "value"}``, non-finite
  floats ``{"$float": "nan" | "inf" | "-inf"}`` (JSON has none); Python's float repr round-trips exactly.

Views for Foxglove (pose, transforms, objects, path) are built apart, in ``foxglove_views.py``.
Decoding only builds classes from the core registry below: a file cannot make us import anything.
"""

from __future__ import annotations

import base64
import dataclasses
import functools
import json
import math
from dataclasses import dataclass
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
from lastmile.recorder import foxglove_views as fv
from lastmile.recorder import record_schemas


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
    if isinstance(value, Enum):  # before int: an IntEnum must come back as its enum
        return {"$enum": type(value).__name__, "value": value.value}
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else {"$float": repr(value)}
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
    """The core message of a lossless JSON record (a ``lastmile.*`` schema)."""
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise RecordingError(f"decode: expected JSON for schema {schema_name}, got {exc}") from None
    return _from_json(doc)


def lidar_from_cloud(cloud: Any) -> sensor_frames.LidarSweep:
    """A ``LidarSweep`` from a decoded ``foxglove.PointCloud`` written by :func:`lossless_record`."""
    names = tuple(f.name for f in cloud.fields)
    if names != fv.LIDAR_FIELD_NAMES or cloud.point_stride != 4 * len(names):
        raise RecordingError(
            f"decode: expected a LiDAR cloud with float32 fields {fv.LIDAR_FIELD_NAMES}, got {names}"
        )
    frame = str(cloud.frame_id)
    points = np.frombuffer(cloud.data, dtype="<f4").reshape(-1, len(names)).astype(np.float32)
    return sensor_frames.LidarSweep(
        stamp=Stamp(fv.stamp_us_of(cloud.timestamp)),
        sensor_id=frame.removeprefix("lidar_"),
        points=points,
    )


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    """How a channel is written: schema name, schema encoding and bytes, message encoding."""

    schema: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str


def foxglove_spec(message: Any) -> ChannelSpec:
    """The channel of a ``foxglove.messages`` object: the SDK's own schema, protobuf."""
    cls: type = type(message)
    return _foxglove_type_spec(cls)


@functools.cache
def _foxglove_type_spec(cls: type) -> ChannelSpec:
    sch = cls.get_schema()  # type: ignore[attr-defined]
    return ChannelSpec(sch.name, sch.encoding, bytes(sch.data), "protobuf")


LIDAR_SPEC = _foxglove_type_spec(fv.fm.PointCloud)
"""The channel of a LiDAR sweep's lossless record: a Foxglove ``PointCloud``."""


def json_spec(message: Any) -> ChannelSpec:
    """The channel of a core message's lossless JSON record, with its documented schema."""
    cls: type = type(message)
    if CLASSES.get(cls.__name__) is not cls:
        raise RecordingError(f"encode: expected a message class of lastmile.core, got {cls.__qualname__}")
    return ChannelSpec(f"lastmile.{cls.__name__}", "jsonschema", record_schemas.schema_for(cls), "json")


def lossless_record(message: Any) -> tuple[ChannelSpec, bytes]:
    """The channel and payload of a message's lossless record.

    A ``LidarSweep`` is a Foxglove ``PointCloud`` in its sensor's frame (every column float32, as the
    sweep holds them: lossless); anything else is our JSON with a documented ``lastmile.<Class>`` schema.
    """
    if isinstance(message, sensor_frames.LidarSweep):
        cloud = fv.point_cloud(
            message.stamp, f"lidar_{message.sensor_id}", fv.LIDAR_FIELD_NAMES, message.points
        )
        return LIDAR_SPEC, cloud.encode()
    return json_spec(message), encode_message(message)
