"""Traffic-light messages: the map's lights, a camera's 2D light detections, the tracked light states.

A light's state is one of :class:`LightState`; "off" also stands for "unknown" (a dark housing, a
detector that cannot tell). Positions are in the map frame (x east, y north, z up from the road).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from lastmile.core.arrays import frozen_array
from lastmile.core.errors import MessageError
from lastmile.core.stamp import Stamp


class LightState(IntEnum):
    """Integer ids so states sit in numeric arrays; the order is the column order of probabilities."""

    RED = 0
    YELLOW = 1
    GREEN = 2
    OFF = 3  # off or unknown

    @property
    def lit(self) -> bool:
        """True for a lit bulb (red, yellow, green)."""
        return self is not LightState.OFF


N_LIGHT_STATES = len(LightState)
_STATE_VALUES = frozenset(int(s) for s in LightState)


def _finite(what: str, **values: float) -> None:
    for key, value in values.items():
        if not (isinstance(value, int | float) and math.isfinite(value)):
            raise MessageError(f"{what}.{key}: expected a finite number, got {value!r}")


def _states_array(values: npt.ArrayLike, what: str) -> np.ndarray:
    """A read-only int64 (N,) array of :class:`LightState` values, refusing anything else."""
    raw = np.asarray(values)
    if raw.ndim != 1:
        raise MessageError(f"{what}: expected a 1-D array of light states, got shape {raw.shape}")
    if raw.size and raw.dtype.kind not in "iu":
        raise MessageError(f"{what}: expected integer LightState values 0..3, got dtype {raw.dtype}")
    bad = [int(v) for v in raw if int(v) not in _STATE_VALUES]
    if bad:
        raise MessageError(
            f"{what}: expected LightState values {sorted(_STATE_VALUES)} (red, yellow, green, off), "
            f"got {bad[0]}"
        )
    return frozen_array(raw.astype(np.int64), np.int64, None, what)


@dataclass(frozen=True, slots=True, kw_only=True)
class MapTrafficLight:
    """One signal head of the HD map, as the traffic-light tracker expects it.

    Attributes:
        light_id: the map's id of the signal head (unique in the map).
        x_m, y_m, z_m: centre of the bulb housing in the map frame (z above the road).
        facing_rad: map-frame heading the lenses face (towards the traffic the light controls).
        width_m, height_m: size of the housing (a three-bulb vertical head is about 0.35 x 1.0 m).
        signal_id: the map's id of the signal (Lanelet2 ``traffic_light`` regulatory element) the head
            belongs to; all heads of one signal show the same state.
        stop_line_id: the map's id of the stop line the signal controls.
        stop_x_m, stop_y_m: midpoint of that stop line in the map frame.
    """

    light_id: str
    x_m: float
    y_m: float
    z_m: float
    facing_rad: float
    width_m: float = 0.35
    height_m: float = 1.0
    signal_id: int = -1
    stop_line_id: int = -1
    stop_x_m: float = 0.0
    stop_y_m: float = 0.0

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        if not self.light_id:
            raise MessageError("MapTrafficLight.light_id: expected a non-empty id, got an empty string")
        _finite(
            f"MapTrafficLight {self.light_id!r}", x_m=self.x_m, y_m=self.y_m, z_m=self.z_m,
            facing_rad=self.facing_rad, width_m=self.width_m, height_m=self.height_m, stop_x_m=self.stop_x_m,
            stop_y_m=self.stop_y_m,
        )  # fmt: skip
        if self.width_m <= 0 or self.height_m <= 0:
            raise MessageError(
                f"MapTrafficLight {self.light_id!r}: expected a positive housing size, got "
                f"{self.width_m} x {self.height_m} m"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class TrafficLightDetections:
    """A 2D traffic-light detector's output for one camera frame.

    Attributes:
        camera_id: which camera captured the frame (a :class:`~lastmile.core.camera_model.PinholeCamera` id).
        boxes: (N, 4) float64 image boxes ``x1_px, y1_px, x2_px, y2_px`` (u right, v down), x1 < x2, y1 < y2.
        states: (N,) int64 detected :class:`LightState` of each box.
        scores: (N,) float64 detector confidence in [0, 1].
    """

    stamp: Stamp
    camera_id: str
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    states: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    scores: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "boxes", frozen_array(self.boxes, np.float64, 4, "TrafficLightDetections.boxes")
        )
        object.__setattr__(self, "states", _states_array(self.states, "TrafficLightDetections.states"))
        object.__setattr__(
            self, "scores", frozen_array(self.scores, np.float64, None, "TrafficLightDetections.scores")
        )
        self.validate()

    def validate(self) -> None:
        n = self.boxes.shape[0]
        if self.states.shape != (n,) or self.scores.shape != (n,):
            raise MessageError(
                f"TrafficLightDetections: expected states and scores of shape ({n},) like boxes, got "
                f"{self.states.shape} and {self.scores.shape}"
            )
        if n and not (
            np.all(self.boxes[:, 2] > self.boxes[:, 0]) and np.all(self.boxes[:, 3] > self.boxes[:, 1])
        ):
            bad = int(
                np.flatnonzero(
                    (self.boxes[:, 2] <= self.boxes[:, 0]) | (self.boxes[:, 3] <= self.boxes[:, 1])
                )[0]
            )
            raise MessageError(
                f"TrafficLightDetections.boxes[{bad}]: expected x1 < x2 and y1 < y2, "
                f"got {self.boxes[bad].tolist()}"
            )
        if n and not (np.all(self.scores >= 0.0) and np.all(self.scores <= 1.0)):
            raise MessageError(
                f"TrafficLightDetections.scores: expected values in [0, 1], got {self.scores.tolist()}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class TrafficLightStates:
    """The traffic-light tracker's output: established light tracks and their estimated states.

    Attributes:
        light_ids: (N,) map ids of the tracked lights.
        track_ids: (N,) int64 track ids (unique over a run, new after a track was dropped).
        states: (N,) int64 :class:`LightState`: the most likely state (the flashing colour when flashing,
            ``OFF`` when no state reaches the tracker's minimum confidence).
        probs: (N, 4) float64 state posterior, columns in :class:`LightState` order; rows sum to 1.
        confidence: (N,) float64 in [0, 1], the tracker's belief in ``states`` (for a flashing light, the
            posterior mass of its colour and of off together).
        flashing: (N,) bool, the duty cycle of the last observations is that of a flashing signal.
        frames_since_seen: (N,) int64 camera frames since the light's last detection.
        stop_line_ids: (N,) int64 map id of the stop line each light controls (-1: none mapped).
        stop_xy_m: (N, 2) float64 midpoint of that stop line in the map frame (x east, y north).
    """

    stamp: Stamp
    light_ids: tuple[str, ...] = ()
    track_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    states: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    probs: np.ndarray = field(default_factory=lambda: np.zeros((0, N_LIGHT_STATES)))
    confidence: np.ndarray = field(default_factory=lambda: np.zeros(0))
    flashing: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    frames_since_seen: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    stop_line_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    stop_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    def __post_init__(self) -> None:
        object.__setattr__(self, "light_ids", tuple(self.light_ids))
        object.__setattr__(
            self,
            "confidence",
            frozen_array(self.confidence, np.float64, None, "TrafficLightStates.confidence"),
        )
        object.__setattr__(
            self,
            "stop_line_ids",
            frozen_array(self.stop_line_ids, np.int64, None, "TrafficLightStates.stop_line_ids"),
        )
        object.__setattr__(
            self, "stop_xy_m", frozen_array(self.stop_xy_m, np.float64, 2, "TrafficLightStates.stop_xy_m")
        )
        object.__setattr__(
            self, "track_ids", frozen_array(self.track_ids, np.int64, None, "TrafficLightStates.track_ids")
        )
        object.__setattr__(self, "states", _states_array(self.states, "TrafficLightStates.states"))
        object.__setattr__(
            self, "probs", frozen_array(self.probs, np.float64, N_LIGHT_STATES, "TrafficLightStates.probs")
        )
        object.__setattr__(
            self, "flashing", frozen_array(self.flashing, np.bool_, None, "TrafficLightStates.flashing")
        )
        object.__setattr__(
            self,
            "frames_since_seen",
            frozen_array(self.frames_since_seen, np.int64, None, "TrafficLightStates.frames_since_seen"),
        )
        self.validate()

    def validate(self) -> None:
        n = len(self.light_ids)
        for name in ("track_ids", "states", "confidence", "flashing", "frames_since_seen", "stop_line_ids"):
            shape = getattr(self, name).shape
            if shape != (n,):
                raise MessageError(
                    f"TrafficLightStates.{name}: expected shape ({n},) like light_ids, got {shape}"
                )
        if self.stop_xy_m.shape != (n, 2):
            raise MessageError(
                f"TrafficLightStates.stop_xy_m: expected shape ({n}, 2), got {self.stop_xy_m.shape}"
            )
        if n and not (np.all(self.confidence >= 0.0) and np.all(self.confidence <= 1.0 + 1e-9)):
            raise MessageError(
                f"TrafficLightStates.confidence: expected values in [0, 1], got {self.confidence.tolist()}"
            )
        if self.probs.shape != (n, N_LIGHT_STATES):
            raise MessageError(
                f"TrafficLightStates.probs: expected shape ({n}, {N_LIGHT_STATES}), got {self.probs.shape}"
            )
        if n and not (np.all(self.probs >= 0.0) and np.allclose(self.probs.sum(axis=1), 1.0, atol=1e-6)):
            raise MessageError(
                f"TrafficLightStates.probs: expected non-negative rows summing to 1, got row sums "
                f"{self.probs.sum(axis=1).tolist()}"
            )
        if np.any(self.frames_since_seen < 0):
            raise MessageError(
                f"TrafficLightStates.frames_since_seen: expected >= 0, got {self.frames_since_seen.tolist()}"
            )
