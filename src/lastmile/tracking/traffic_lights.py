"""Traffic-light tracker (aUToronto 6.4): map-projected lights, association, N_birth/N_death, HMM, flashing.

Per camera frame of :class:`~lastmile.core.traffic_light_messages.TrafficLightDetections`:
1. fusion (:mod:`.traffic_light_fusion`): the map lights that camera should see are projected to image
   boxes and paired one-to-one with the detected boxes (Hungarian, gated);
2. tracking: a mapped light paired in ``n_birth`` successive frames becomes a track with a new id; a
   track not paired for ``n_death`` successive camera frames (of any camera) is dropped;
3. state estimation (:mod:`.traffic_light_state`): an HMM forward filter per track (transition prior from
   the signal sequence, emission from the detector's confusion matrix) and the duty-cycle flashing test
   over the last ``flash_window`` observed states.

A frame older than a track's last update (frames may arrive out of order) is applied without a
prediction step: the time step is clipped at zero rather than the frame being dropped.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import (
    N_LIGHT_STATES,
    LightState,
    MapTrafficLight,
    TrafficLightDetections,
    TrafficLightStates,
)
from lastmile.tracking import traffic_light_fusion as fusion
from lastmile.tracking import traffic_light_state as hmm

# A detector tested on its own data: rows true state, columns detected state (red, yellow, green, off).
# Red and yellow are the usual confusion (both warm colours), a lit bulb in glare reads as off.
DEFAULT_CONFUSION = (
    (0.90, 0.06, 0.01, 0.03),
    (0.08, 0.86, 0.03, 0.03),
    (0.01, 0.03, 0.93, 0.03),
    (0.04, 0.03, 0.03, 0.90),
)


@dataclass(frozen=True, slots=True, kw_only=True)
class TrafficLightTrackerConfig:
    """Parameters of :class:`TrafficLightTracker`.

    Attributes:
        n_birth: successive paired frames before a light becomes a track (aUToronto's N_birth).
        n_death: successive camera frames without a pairing before a track is dropped (N_death).
        gate_px: largest centre distance of a projected and a detected box (pixels).
        iou_weight: weight of (1 - IoU) in the association cost (dimensionless).
        max_range_m: lights farther from a camera are not expected in it.
        max_view_angle_rad: lights whose lenses face more than this away from a camera are not expected.
        dwell_s: mean time in red, yellow, green, off (s) for the HMM transition prior.
        p_out_of_sequence: share of state changes against green -> yellow -> red -> green.
        confusion: (4, 4) detector confusion ``C[true, detected]``, rows sum to 1.
        flash_window: N, the number of last observed states of the duty-cycle test; 30 camera frames at
            15 Hz span two cycles of a 1 Hz flasher (MUTCD: 50-60 flashes per minute), so the window's
            on ratio is the flasher's duty cycle whatever the phase.
        flash_on_ratio: the band (lower, upper) of the on ratio of a flashing light (MUTCD 1/2..2/3).
        min_confidence: a track whose best state has less posterior mass is published as ``OFF``.
    """

    n_birth: int = 3
    n_death: int = 15
    gate_px: float = 40.0
    iou_weight: float = 1.0
    max_range_m: float = 70.0
    max_view_angle_rad: float = math.radians(60.0)
    dwell_s: tuple[float, float, float, float] = (25.0, 3.5, 25.0, 30.0)
    p_out_of_sequence: float = 0.05
    confusion: tuple[tuple[float, ...], ...] = DEFAULT_CONFUSION
    flash_window: int = 30
    flash_on_ratio: tuple[float, float] = (0.5, 2.0 / 3.0)
    min_confidence: float = 0.5

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        if self.n_birth < 1 or self.n_death < 1 or self.flash_window < 2:
            raise ConfigError(
                "TrafficLightTrackerConfig: expected n_birth >= 1, n_death >= 1, flash_window >= 2, got "
                f"{self.n_birth}, {self.n_death}, {self.flash_window}"
            )
        if self.gate_px <= 0 or self.iou_weight < 0 or self.max_range_m <= 0:
            raise ConfigError(
                "TrafficLightTrackerConfig: expected gate_px > 0, iou_weight >= 0, max_range_m > 0, got "
                f"{self.gate_px}, {self.iou_weight}, {self.max_range_m}"
            )
        if not 0 < self.max_view_angle_rad <= math.pi:
            raise ConfigError(
                "TrafficLightTrackerConfig.max_view_angle_rad: expected (0, pi], "
                f"got {self.max_view_angle_rad}"
            )
        if len(self.dwell_s) != N_LIGHT_STATES or min(self.dwell_s) <= 0:
            raise ConfigError(
                f"TrafficLightTrackerConfig.dwell_s: expected 4 positive dwell times (s), got {self.dwell_s}"
            )
        if not 0 <= self.p_out_of_sequence <= 1:
            raise ConfigError(
                f"TrafficLightTrackerConfig.p_out_of_sequence: expected [0, 1], got {self.p_out_of_sequence}"
            )
        c = np.asarray(self.confusion, dtype=float)
        if (
            c.shape != (N_LIGHT_STATES, N_LIGHT_STATES)
            or np.any(c < 0)
            or not np.allclose(c.sum(axis=1), 1.0)
        ):
            raise ConfigError(
                "TrafficLightTrackerConfig.confusion: expected a 4x4 matrix of non-negative rows "
                "summing to 1, "
                f"got {self.confusion}"
            )
        lo, hi = self.flash_on_ratio
        if not 0 < lo < hi < 1:
            raise ConfigError(
                f"TrafficLightTrackerConfig.flash_on_ratio: expected 0 < lo < hi < 1, got {lo}, {hi}"
            )
        if not 0 <= self.min_confidence <= 1:
            raise ConfigError(
                f"TrafficLightTrackerConfig.min_confidence: expected [0, 1], got {self.min_confidence}"
            )


@dataclass(slots=True)
class _LightTrack:
    """Tracker state of one mapped light (a candidate while ``track_id`` is -1)."""

    hits: int = 0  # successive paired frames (birth counter)
    misses: int = 0  # successive camera frames without a pairing
    track_id: int = -1
    prob: np.ndarray = field(default_factory=lambda: np.full(N_LIGHT_STATES, 1.0 / N_LIGHT_STATES))
    last_us: int | None = None
    history: deque[int] = field(default_factory=deque)


class TrafficLightTracker:
    """Tracks the mapped lights through the 2D detections of one or more cameras."""

    def __init__(
        self,
        lights: tuple[MapTrafficLight, ...],
        cameras: tuple[PinholeCamera, ...],
        config: TrafficLightTrackerConfig | None = None,
    ) -> None:
        ids = [lt.light_id for lt in lights]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"TrafficLightTracker: expected unique light ids, got {ids}")
        self.config = config or TrafficLightTrackerConfig()
        self._lights = tuple(lights)
        self._table = fusion.light_positions(self._lights)
        self._cameras = {cam.camera_id: cam for cam in cameras}
        if not self._cameras:
            raise ConfigError("TrafficLightTracker: expected at least one camera, got none")
        self._confusion = np.asarray(self.config.confusion, dtype=np.float64)
        self._dwell = np.asarray(self.config.dwell_s, dtype=np.float64)
        self._tracks = [_LightTrack(history=deque(maxlen=self.config.flash_window)) for _ in self._lights]
        self._next_id = 1
        self._last_stamp = Stamp(0)

    @property
    def lights(self) -> tuple[MapTrafficLight, ...]:
        return self._lights

    def update(self, detections: TrafficLightDetections, map_from_base: SE2) -> None:
        """Fuse one camera frame's detections, taken with the vehicle at ``map_from_base``.

        Raises:
            MessageError: the frame comes from a camera the tracker was not given.
        """
        cam = self._cameras.get(detections.camera_id)
        if cam is None:
            raise MessageError(
                f"TrafficLightDetections.camera_id: expected one of {sorted(self._cameras)}, "
                f"got {detections.camera_id!r}"
            )
        cfg = self.config
        now_us = int(detections.stamp)
        self._last_stamp = Stamp(max(self._last_stamp, now_us))
        projected = fusion.project_lights(
            cam, self._table, map_from_base, cfg.max_range_m, cfg.max_view_angle_rad
        )
        pairs = fusion.associate(projected.boxes, detections.boxes, cfg.gate_px, cfg.iou_weight)
        paired = {int(projected.indices[p]): d for p, d in pairs}
        for i, tr in enumerate(self._tracks):
            det = paired.get(i)
            if det is None:
                tr.hits = 0
                tr.misses += 1
                if tr.track_id >= 0 and tr.misses >= cfg.n_death:
                    self._tracks[i] = _LightTrack(history=deque(maxlen=cfg.flash_window))
                elif tr.track_id >= 0:
                    self._predict(tr, now_us)
                continue
            tr.misses = 0
            tr.hits += 1
            state, score = int(detections.states[det]), float(detections.scores[det])
            self._predict(tr, now_us)
            tr.prob = hmm.hmm_update(tr.prob, state, score, self._confusion)
            tr.history.append(state)
            if tr.track_id < 0 and tr.hits >= cfg.n_birth:
                tr.track_id = self._next_id
                self._next_id += 1

    def _predict(self, tr: _LightTrack, now_us: int) -> None:
        if tr.last_us is not None:
            dt_s = max(0, now_us - tr.last_us) * 1e-6
            if dt_s > 0:
                tr.prob = hmm.hmm_predict(
                    tr.prob, hmm.transition_matrix(dt_s, self._dwell, self.config.p_out_of_sequence)
                )
        tr.last_us = now_us if tr.last_us is None else max(tr.last_us, now_us)

    def states(self) -> TrafficLightStates:
        """The established tracks (candidates are not published), stamped with the newest frame."""
        cfg = self.config
        rows = [(lt, tr) for lt, tr in zip(self._lights, self._tracks, strict=True) if tr.track_id >= 0]
        states, conf, flashing = [], [], []
        for _, tr in rows:
            flash, colour = hmm.duty_cycle(list(tr.history), *cfg.flash_on_ratio)
            flash = flash and len(tr.history) >= cfg.flash_window and colour is not LightState.OFF
            if flash:
                states.append(int(colour))
                conf.append(float(tr.prob[int(colour)] + tr.prob[int(LightState.OFF)]))
            else:
                best = int(np.argmax(tr.prob))
                p = float(tr.prob[best])
                states.append(best if p >= cfg.min_confidence else int(LightState.OFF))
                conf.append(p if p >= cfg.min_confidence else float(tr.prob[int(LightState.OFF)]))
            flashing.append(flash)
        return TrafficLightStates(
            stamp=self._last_stamp,
            light_ids=tuple(lt.light_id for lt, _ in rows),
            track_ids=np.array([tr.track_id for _, tr in rows], dtype=np.int64),
            states=np.array(states, dtype=np.int64),
            probs=np.array([tr.prob for _, tr in rows]).reshape(-1, N_LIGHT_STATES),
            confidence=np.clip(np.array(conf, dtype=np.float64), 0.0, 1.0),
            flashing=np.array(flashing, dtype=bool),
            frames_since_seen=np.array([tr.misses for _, tr in rows], dtype=np.int64),
            stop_line_ids=np.array([lt.stop_line_id for lt, _ in rows], dtype=np.int64),
            stop_xy_m=np.array([[lt.stop_x_m, lt.stop_y_m] for lt, _ in rows], dtype=np.float64).reshape(
                -1, 2
            ),
        )
