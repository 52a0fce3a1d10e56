"""Sensor frames: what real sensors on the shuttle output, timestamped at capture.

Frames reach the stack after a latency and may arrive out of order; ``stamp`` is always the capture
time. Positions of the INS are in the map frame (the INS is configured with the map's origin); radar
objects are in the radar's own frame (x forward along its boresight, y left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.arrays import check_frozen_array, frozen_array
from lastmile.core.errors import MessageError
from lastmile.core.gnss_messages import GnssQuality
from lastmile.core.safety_messages import OperatorInput
from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import TrafficLightDetections


def _check_finite(name: str, **values: float) -> None:
    for key, value in values.items():
        if value != value or value in (float("inf"), float("-inf")):
            raise MessageError(f"{name}.{key}: expected a finite number, got {value}")


@dataclass(frozen=True, slots=True, kw_only=True)
class GnssInsFrame:
    """RTK GNSS / INS solution: pose of the base (rear axle centre) in the map frame.

    ``fix_ok`` False means the receiver reports no usable solution (outage); the values are then
    the receiver's last dead-reckoned guess and must not be trusted. ``quality`` is the solution type
    the receiver reports (RTK fixed on a healthy RTK receiver; float or single where the sky or a
    facade degrade it), with ``pos_std_m`` its reported one-sigma accuracy per axis.
    """

    stamp: Stamp
    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    pos_std_m: float
    yaw_std_rad: float
    fix_ok: bool = True
    quality: GnssQuality = GnssQuality.RTK_FIXED

    def validate(self) -> None:
        _check_finite(
            "GnssInsFrame", x_m=self.x_m, y_m=self.y_m, yaw_rad=self.yaw_rad, speed_mps=self.speed_mps
        )
        if self.pos_std_m <= 0 or self.yaw_std_rad <= 0:
            raise MessageError(
                f"GnssInsFrame: expected positive std devs, got {self.pos_std_m}, {self.yaw_std_rad}"
            )

    def validate_for_fusion(self) -> None:
        """``validate``, and what a filter needs besides: finite std devs and a non-negative stamp."""
        self.validate()
        if not (math.isfinite(self.pos_std_m) and math.isfinite(self.yaw_std_rad)):
            raise MessageError(
                f"GnssInsFrame: expected finite std devs, got {self.pos_std_m}, {self.yaw_std_rad}"
            )
        if self.stamp < 0:
            raise MessageError(f"GnssInsFrame.stamp: expected a non-negative stamp, got {self.stamp}")


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuFrame:
    """IMU: yaw rate (counter-clockwise positive) and body accelerations (x forward, y left)."""

    stamp: Stamp
    yaw_rate_radps: float
    accel_x_mps2: float
    accel_y_mps2: float

    def validate(self) -> None:
        _check_finite("ImuFrame", yaw_rate_radps=self.yaw_rate_radps, accel_x_mps2=self.accel_x_mps2)


@dataclass(frozen=True, slots=True, kw_only=True)
class WheelOdometryFrame:
    """Wheel-speed and steering feedback from the vehicle bus (CAN).

    Attributes:
        cycle: the message's alive counter, as safety-relevant CAN messages carry one (-1: not
            reported). At standstill the speed legitimately repeats; the counter tells a frozen
            gateway from a parked vehicle.
    """

    stamp: Stamp
    speed_mps: float
    steer_front_rad: float
    steer_rear_rad: float
    cycle: int = -1

    def validate(self) -> None:
        _check_finite("WheelOdometryFrame", speed_mps=self.speed_mps, steer_front_rad=self.steer_front_rad)
        if not isinstance(self.cycle, int) or self.cycle < -1:
            raise MessageError(f"WheelOdometryFrame.cycle: expected an int >= -1, got {self.cycle!r}")


RADAR_COLUMNS = ("x_m", "y_m", "vx_mps", "vy_mps", "rcs_dbsm", "range_rate_mps")
"""Columns of :attr:`RadarFrame.objects`: position and over-ground velocity in the radar frame."""


@dataclass(frozen=True, slots=True, kw_only=True)
class RadarFrame:
    """A radar's object list (cluster/object mode as automotive radars output it).

    Attributes:
        sensor_id: which radar ("front", "rear").
        objects: (N, 6) float64, columns :data:`RADAR_COLUMNS`; velocities are over ground, expressed
            in the radar frame (the radar compensates its own motion from the vehicle speed it is fed).
        cycle: the radar's measurement-cycle counter, as automotive radars send it with each object
            list (-1: not reported). A frozen driver repeats it, so a frozen empty list is detectable.
        raw_detections: how many reflections the radar's own signal processing found this cycle,
            static clutter included (the ARS 408 reports it as its near and far cluster counts);
            -1: not reported. A working radar facing a road always sees ground, curb and pole
            returns, so an empty object list with zero raw reflections is a blocked (blind) radar,
            while an empty list over the usual clutter is just an empty road.
    """

    stamp: Stamp
    sensor_id: str
    objects: np.ndarray = field(default_factory=lambda: np.zeros((0, len(RADAR_COLUMNS))))
    cycle: int = -1
    raw_detections: int = -1

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "objects", frozen_array(self.objects, np.float64, len(RADAR_COLUMNS), "RadarFrame.objects")
        )

    def validate(self) -> None:
        check_frozen_array(self.objects, np.float64, len(RADAR_COLUMNS), "RadarFrame.objects")
        if not isinstance(self.cycle, int) or self.cycle < -1:
            raise MessageError(f"RadarFrame.cycle: expected an int >= -1, got {self.cycle!r}")
        if not isinstance(self.raw_detections, int) or self.raw_detections < -1:
            raise MessageError(
                f"RadarFrame.raw_detections: expected an int >= -1, got {self.raw_detections!r}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class DoorSensorFrame:
    """The in-door sensor: door state and whether someone stands in the doorway."""

    stamp: Stamp
    door_open: bool
    person_in_doorway: bool

    def validate(self) -> None:
        """Booleans only: nothing can be out of range."""


@dataclass(frozen=True, slots=True, kw_only=True)
class StopCallFrame:
    """A stop's call button (wired to the shuttle over V2I) or an onboard seat button.

    ``stop_id`` names the stop the request is for; ``source`` is "stop_button" or "seat_button".
    """

    stamp: Stamp
    stop_id: str
    source: str

    def validate(self) -> None:
        if self.source not in ("stop_button", "seat_button", "dispatch"):
            raise MessageError(
                f"StopCallFrame.source: expected stop_button, seat_button or dispatch, got {self.source!r}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class DropOffRequestFrame:
    """A passenger on board pressed the drop-off button by their seat: let me off at the next safe place.

    Snow Lion's function button: the task manager cuts the route short to a temporary destination. It
    names no stop (a seat button that does is a :class:`StopCallFrame` with source "seat_button").

    Attributes:
        seat: the seat whose button was pressed (0-based; -1: not reported).
    """

    stamp: Stamp
    seat: int = -1

    def validate(self) -> None:
        if isinstance(self.seat, bool) or not isinstance(self.seat, int) or self.seat < -1:
            raise MessageError(f"DropOffRequestFrame.seat: expected an int >= -1, got {self.seat!r}")


@dataclass(frozen=True, slots=True, kw_only=True)
class CrossingPresenceFrame:
    """An infrastructure camera's report relayed to the shuttle (NUS): pedestrians on a crossing or not.

    ``crosswalk_id`` is the HD map's crosswalk id; ``captured`` when the node saw it (its clock).
    """

    stamp: Stamp
    node_id: str
    crosswalk_id: int
    pedestrians_present: bool
    captured: Stamp

    def validate(self) -> None:
        if not self.node_id:
            raise MessageError("CrossingPresenceFrame.node_id: expected a node id, got an empty string")
        if self.crosswalk_id < 0:
            raise MessageError(f"CrossingPresenceFrame.crosswalk_id: expected >= 0, got {self.crosswalk_id}")


LIDAR_COLUMNS = ("x_m", "y_m", "z_m", "intensity", "ring", "t_offset_us")


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarSweep:
    """One LiDAR sweep in the sensor frame; each point keeps its own capture-time offset.

    Attributes:
        points: (N, 6) float32, columns :data:`LIDAR_COLUMNS`; ``t_offset_us`` is relative to ``stamp``.
    """

    stamp: Stamp
    sensor_id: str
    points: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "points", frozen_array(self.points, np.float32, len(LIDAR_COLUMNS), "LidarSweep.points")
        )

    def validate(self) -> None:
        check_frozen_array(self.points, np.float32, len(LIDAR_COLUMNS), "LidarSweep.points")


CAMERA_BOX_COLUMNS = ("u_min_px", "v_min_px", "u_max_px", "v_max_px", "class_id", "score")


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraDetections:
    """2D boxes from a camera's detector (a model-free simulator detector or a real network).

    Attributes:
        boxes: (N, 6) float32, columns :data:`CAMERA_BOX_COLUMNS`, pixel coordinates.
    """

    stamp: Stamp
    camera_id: str
    boxes: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "boxes",
            frozen_array(self.boxes, np.float32, len(CAMERA_BOX_COLUMNS), "CameraDetections.boxes"),
        )

    def validate(self) -> None:
        check_frozen_array(self.boxes, np.float32, len(CAMERA_BOX_COLUMNS), "CameraDetections.boxes")


SensorFrame = (
    GnssInsFrame
    | ImuFrame
    | WheelOdometryFrame
    | RadarFrame
    | DoorSensorFrame
    | StopCallFrame
    | DropOffRequestFrame
    | CrossingPresenceFrame
    | LidarSweep
    | CameraDetections
    | TrafficLightDetections
    | OperatorInput
)
"""Everything the simulator (or a real vehicle) may hand to the vehicle: sensors, V2I, the operator.
Their names (stream, fault target, recording topic) are registered in :mod:`lastmile.core.frame_kinds`."""
