"""What a failing sensor does to the content of its frames, one implementation per frame type.

``blind`` (a covered or dead sensor that still cycles), ``nan_values`` (a driver publishing NaN) and
``garbage`` (finite but physically implausible values, as a corrupted bus or a failing unit sends)
dispatch on the frame's type: a new frame type registers its own, and a type without one passes
through unchanged (its fault is then only in its timing).
"""

from __future__ import annotations

import dataclasses
import math
from functools import singledispatch

import numpy as np

from lastmile.core.sensor_frames import (
    CameraDetections,
    DoorSensorFrame,
    GnssInsFrame,
    ImuFrame,
    LidarSweep,
    RadarFrame,
    SensorFrame,
    WheelOdometryFrame,
)

NAN = float("nan")


@singledispatch
def blind(frame: SensorFrame) -> SensorFrame:
    """The frame of a sensor that sees nothing."""
    return frame


@blind.register
def _(frame: RadarFrame) -> SensorFrame:
    # A blocked radome: no reflections at all, clutter included (the radar still cycles).
    return dataclasses.replace(frame, objects=np.zeros((0, frame.objects.shape[1])), raw_detections=0)


@blind.register
def _(frame: LidarSweep) -> SensorFrame:
    return dataclasses.replace(frame, points=np.zeros((0, frame.points.shape[1]), np.float32))


@blind.register
def _(frame: CameraDetections) -> SensorFrame:
    return dataclasses.replace(frame, boxes=np.zeros((0, frame.boxes.shape[1]), np.float32))


@blind.register
def _(frame: GnssInsFrame) -> SensorFrame:
    return dataclasses.replace(frame, fix_ok=False)


@blind.register
def _(frame: WheelOdometryFrame) -> SensorFrame:
    return dataclasses.replace(frame, speed_mps=0.0)


@blind.register
def _(frame: ImuFrame) -> SensorFrame:
    return dataclasses.replace(frame, yaw_rate_radps=0.0, accel_x_mps2=0.0, accel_y_mps2=0.0)


@blind.register
def _(frame: DoorSensorFrame) -> SensorFrame:
    return dataclasses.replace(frame, person_in_doorway=False)


@singledispatch
def nan_values(frame: SensorFrame) -> SensorFrame:
    """The frame of a driver that publishes NaN in its scalar fields."""
    return frame


@nan_values.register
def _(frame: GnssInsFrame) -> SensorFrame:
    return dataclasses.replace(frame, x_m=NAN, y_m=NAN)


@nan_values.register
def _(frame: ImuFrame) -> SensorFrame:
    return dataclasses.replace(frame, yaw_rate_radps=NAN)


@nan_values.register
def _(frame: WheelOdometryFrame) -> SensorFrame:
    return dataclasses.replace(frame, speed_mps=NAN)


@singledispatch
def garbage(frame: SensorFrame, rng: np.random.Generator) -> SensorFrame:
    """Finite but physically implausible values, as a corrupted bus or a failing unit sends."""
    del rng
    return frame


@garbage.register
def _(frame: GnssInsFrame, rng: np.random.Generator) -> SensorFrame:
    return dataclasses.replace(
        frame,
        x_m=frame.x_m + float(rng.uniform(-2000.0, 2000.0)),
        y_m=frame.y_m + float(rng.uniform(-2000.0, 2000.0)),
        yaw_rad=float(rng.uniform(-math.pi, math.pi)),
    )


@garbage.register
def _(frame: ImuFrame, rng: np.random.Generator) -> SensorFrame:
    return dataclasses.replace(frame, yaw_rate_radps=float(rng.uniform(-20.0, 20.0)))


@garbage.register
def _(frame: WheelOdometryFrame, rng: np.random.Generator) -> SensorFrame:
    return dataclasses.replace(frame, speed_mps=float(rng.uniform(0.0, 80.0)))


@garbage.register
def _(frame: DoorSensorFrame, rng: np.random.Generator) -> SensorFrame:
    return dataclasses.replace(
        frame, door_open=bool(rng.integers(2)), person_in_doorway=bool(rng.integers(2))
    )


@garbage.register
def _(frame: RadarFrame, rng: np.random.Generator) -> SensorFrame:
    n = int(rng.integers(20, 60))
    objects = np.column_stack(
        [
            rng.uniform(-300.0, 300.0, n),
            rng.uniform(-300.0, 300.0, n),
            rng.uniform(-150.0, 150.0, n),
            rng.uniform(-150.0, 150.0, n),
            rng.uniform(-60.0, 60.0, n),
            rng.uniform(-150.0, 150.0, n),
        ]
    )
    return dataclasses.replace(frame, objects=objects)
