"""What the reliability monitor checks in a single sensor frame: which stream it belongs to, whether
it repeats its predecessor (a frozen driver), and whether its content is usable at all. The content
checks dispatch on the frame's type (``functools.singledispatch``): a new frame type registers its own
digest or plausibility check beside the generic one."""

from __future__ import annotations

import math
from dataclasses import fields
from functools import singledispatch

import numpy as np

from lastmile.core import frame_kinds
from lastmile.core.errors import MessageError
from lastmile.core.sensor_frames import (
    GnssInsFrame,
    ImuFrame,
    LidarSweep,
    RadarFrame,
    SensorFrame,
    WheelOdometryFrame,
)

_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


def _field_names(kind: type) -> tuple[str, ...]:
    """The dataclass fields of a frame type, in order (looked up once per type, not per frame)."""
    names = _FIELD_NAMES.get(kind)
    if names is None:
        names = _FIELD_NAMES[kind] = tuple(f.name for f in fields(kind))
    return names


def sensor_key(frame: SensorFrame) -> str | None:
    """The stream a frame belongs to (None for event-driven frames such as stop calls)."""
    return frame_kinds.stream_key(frame)


class ArrayBytes:
    """An array's exact content as a digest part: equal when dtype, shape and every byte are (as
    ``hash(a.tobytes())`` compares them, without copying a LiDAR sweep's megabyte each frame).

    The comparison looks at the first bytes before the rest: a healthy sensor's noise makes
    consecutive frames differ there, so only a frozen stream pays for the whole comparison. A
    message's arrays are read-only; a writable one is copied, so that a later change cannot make it
    equal to its successor.
    """

    __slots__ = ("_array",)
    _HEAD = 256  # elements compared first

    def __init__(self, array: np.ndarray) -> None:
        self._array = array if not array.flags.writeable else array.copy()

    def _bytes_view(self) -> np.ndarray:
        return np.ascontiguousarray(self._array).reshape(-1).view(np.uint8)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ArrayBytes):
            return NotImplemented
        a, b = self._array, other._array
        if a.dtype != b.dtype or a.shape != b.shape:
            return False
        va, vb = self._bytes_view(), other._bytes_view()
        head = self._HEAD * a.dtype.itemsize
        return bool(np.array_equal(va[:head], vb[:head]) and np.array_equal(va[head:], vb[head:]))

    def __hash__(self) -> int:
        return hash((self._array.dtype.str, self._array.shape, self._array.tobytes()))


@singledispatch
def payload_digest(frame: SensorFrame) -> tuple[object, ...] | None:
    """Everything but the stamp, hashable; None when there is no content to compare (empty lists).

    Types whose healthy frames may legitimately repeat, or carry a counter that makes every healthy
    frame differ, register their own digest below.
    """
    parts: list[object] = []
    for name in _field_names(type(frame)):
        if name == "stamp":
            continue
        value = getattr(frame, name)
        if isinstance(value, np.ndarray):
            if value.size == 0:
                return None
            parts.append(ArrayBytes(value))
        else:
            parts.append(value)
    return tuple(parts)


@payload_digest.register
def _(frame: WheelOdometryFrame) -> tuple[object, ...] | None:
    # An alive counter makes every healthy frame differ, standing still or not. Without one, odometry
    # at standstill legitimately repeats (no content to compare); moving, wheel-speed noise makes every
    # frame differ, so a repeat there is a frozen driver.
    if frame.cycle >= 0:
        return (frame.cycle, frame.speed_mps, frame.steer_front_rad, frame.steer_rear_rad)
    if frame.speed_mps < 0.1:
        return None
    return payload_digest.dispatch(object)(frame)


@payload_digest.register
def _(frame: RadarFrame) -> tuple[object, ...] | None:
    # The cycle counter advances with every healthy list, empty or not.
    if frame.cycle >= 0:
        return (frame.cycle, hash(frame.objects.tobytes()))
    return payload_digest.dispatch(object)(frame)


@singledispatch
def point_count(frame: SensorFrame) -> int | None:
    """How many returns a frame carries, for sensors with a minimum (None: not a point sensor)."""
    return None


@point_count.register
def _(frame: LidarSweep) -> int | None:
    return int(frame.points.shape[0])


@point_count.register
def _(frame: RadarFrame) -> int | None:
    # Raw detections before tracking, clutter included; -1 when the radar does not report them.
    return frame.raw_detections if frame.raw_detections >= 0 else None


PLAUSIBLE_SPEED_MPS = 15.0  # odometry or GNSS speed: a 20 km/h shuttle never reaches it
PLAUSIBLE_YAW_RATE_RADPS = 2.0  # beyond what its steering allows at any speed
PLAUSIBLE_ACCEL_MPS2 = 15.0
PLAUSIBLE_RADAR_RANGE_M = 250.0  # beyond every automotive radar's reach
PLAUSIBLE_RADAR_SPEED_MPS = 70.0  # over-ground speed of anything on a campus road


def garbage_reason(frame: SensorFrame) -> str:
    """Why a frame's content is unusable ('' if it is fine): invalid, non-finite or implausible."""
    try:
        frame.validate()
    except MessageError as exc:
        return str(exc)
    for name in _field_names(type(frame)):
        value = getattr(frame, name)
        if isinstance(value, float) and not math.isfinite(value):
            return f"{type(frame).__name__}.{name} is {value}"
    return _implausible(frame)


@singledispatch
def _implausible(frame: SensorFrame) -> str:
    """Finite values a working sensor cannot report on this vehicle (a corrupt bus or a failing unit)."""
    return ""


@_implausible.register
def _(frame: WheelOdometryFrame) -> str:
    if not 0.0 <= frame.speed_mps <= PLAUSIBLE_SPEED_MPS:
        return f"odometry speed {frame.speed_mps:.1f} m/s outside [0, {PLAUSIBLE_SPEED_MPS}]"
    return ""


@_implausible.register
def _(frame: GnssInsFrame) -> str:
    if abs(frame.speed_mps) > PLAUSIBLE_SPEED_MPS:
        return f"GNSS speed {frame.speed_mps:.1f} m/s above {PLAUSIBLE_SPEED_MPS}"
    return ""


@_implausible.register
def _(frame: ImuFrame) -> str:
    if (
        abs(frame.yaw_rate_radps) > PLAUSIBLE_YAW_RATE_RADPS
        or max(abs(frame.accel_x_mps2), abs(frame.accel_y_mps2)) > PLAUSIBLE_ACCEL_MPS2
    ):
        return f"IMU yaw rate {frame.yaw_rate_radps:.2f} rad/s or acceleration beyond physical limits"
    return ""


@_implausible.register
def _(frame: RadarFrame) -> str:
    if not len(frame.objects):
        return ""
    obj = frame.objects
    far = float(np.hypot(obj[:, 0], obj[:, 1]).max())
    fast = float(np.hypot(obj[:, 2], obj[:, 3]).max())
    if far > PLAUSIBLE_RADAR_RANGE_M or fast > PLAUSIBLE_RADAR_SPEED_MPS:
        return f"radar objects at {far:.0f} m or {fast:.0f} m/s: beyond the sensor's physics"
    return ""
