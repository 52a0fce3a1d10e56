"""One registry of sensor-frame types: the stream each frame belongs to, the fault target that captured
it, and the topic it is recorded on. A new frame type is one entry here (and a handler where a module
consumes it), not an edit in every module that names frames."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from lastmile.core.errors import MessageError
from lastmile.core.safety_messages import OperatorInput
from lastmile.core.sensor_frames import (
    CameraDetections,
    CrossingPresenceFrame,
    DoorSensorFrame,
    DropOffRequestFrame,
    GnssInsFrame,
    ImuFrame,
    LidarSweep,
    RadarFrame,
    SensorFrame,
    StopCallFrame,
    WheelOdometryFrame,
)
from lastmile.core.traffic_light_messages import TrafficLightDetections


@dataclass(frozen=True, slots=True)
class FrameKind:
    """How the infrastructure names frames of one type.

    Attributes:
        stream: the reliability monitor's stream key (None: event-driven frames, no rate to watch).
        sensor: the fault-injection target name of the sensor that captured it (None: not faultable).
        topic: the black-box topic it is recorded on.
    """

    stream: Callable[[Any], str | None]
    sensor: Callable[[Any], str | None]
    topic: Callable[[Any], str]


def _fixed(name: str | None) -> Callable[[Any], str | None]:
    return lambda _frame: name


# Radars keep their bare ids as stream keys (the suite's first streams); LiDARs and cameras are
# prefixed, since a front radar, a front LiDAR and a front camera are three streams.
FRAME_KINDS: dict[type, FrameKind] = {
    GnssInsFrame: FrameKind(_fixed("gnss"), _fixed("gnss"), lambda f: "/sensors/gnss"),
    ImuFrame: FrameKind(_fixed("imu"), _fixed("imu"), lambda f: "/sensors/imu"),
    WheelOdometryFrame: FrameKind(_fixed("odom"), _fixed("odom"), lambda f: "/sensors/odometry"),
    DoorSensorFrame: FrameKind(_fixed("door"), _fixed("door"), lambda f: "/sensors/door"),
    RadarFrame: FrameKind(
        lambda f: f.sensor_id, lambda f: f"radar_{f.sensor_id}", lambda f: f"/sensors/radar/{f.sensor_id}"
    ),
    LidarSweep: FrameKind(
        lambda f: f"lidar_{f.sensor_id}",
        lambda f: f"lidar_{f.sensor_id}",
        lambda f: f"/sensors/lidar/{f.sensor_id}",
    ),
    CameraDetections: FrameKind(
        lambda f: f"camera_{f.camera_id}",
        lambda f: f"camera_{f.camera_id}",
        lambda f: f"/sensors/camera/{f.camera_id}",
    ),
    TrafficLightDetections: FrameKind(
        lambda f: f"traffic_lights.{f.camera_id}",
        _fixed(None),
        lambda f: f"/sensors/traffic_lights/{f.camera_id}",
    ),
    StopCallFrame: FrameKind(_fixed(None), _fixed(None), lambda f: "/sensors/stop_call"),
    DropOffRequestFrame: FrameKind(_fixed(None), _fixed(None), lambda f: "/sensors/drop_off_request"),
    CrossingPresenceFrame: FrameKind(_fixed(None), _fixed(None), lambda f: "/v2i/crossing_presence"),
    OperatorInput: FrameKind(_fixed(None), _fixed(None), lambda f: "/operator/input"),
}


def frame_kind(frame: SensorFrame) -> FrameKind:
    """The registry entry of ``frame``'s type; a type not registered is a programming error, named."""
    kind = FRAME_KINDS.get(type(frame))
    if kind is None:
        known = sorted(t.__name__ for t in FRAME_KINDS)
        raise MessageError(f"frame_kind: expected one of {known}, got {type(frame).__name__}")
    return kind


def stream_key(frame: SensorFrame) -> str | None:
    """The stream a frame belongs to (None for event-driven frames such as stop calls)."""
    return frame_kind(frame).stream(frame)


def sensor_name(frame: SensorFrame) -> str | None:
    """The fault target name of the sensor that captured ``frame`` (None: not a faultable sensor)."""
    return frame_kind(frame).sensor(frame)


def frame_topic(frame: SensorFrame) -> str:
    """The topic a frame is recorded on."""
    return frame_kind(frame).topic(frame)
