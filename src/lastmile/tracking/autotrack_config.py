"""aUToTrack's parameters: per-class lifecycle and motion noise, association, class HMM, rollback window."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.tracking.association import AssociationConfig
from lastmile.tracking.class_hmm import ClassHmmConfig


@dataclass(frozen=True, slots=True, kw_only=True)
class ClassParams:
    """Per-class tracker parameters.

    Attributes:
        gate_m: centre-distance gate for association.
        birth_min_score: detections scoring lower update tracks but never start one.
        birth_min_evidence: a trial track becomes full only once the sum of its detections' scores
            reaches this, besides ``t_birth_s`` (scores read as the detector's log-odds that the object
            exists, so the sum is the track's accumulated existence evidence, a sequential test: one
            confident detection suffices, a run of doubtful ones needs many); -inf: off.
        t_birth_s: detected over this long (first to latest detection) before a trial track is full.
        t_expire_s: a full track undetected for longer is demoted (no longer published).
        t_prune_s: a track undetected for longer is deleted.
        accel_std_mps2: white-acceleration process noise.
        yaw_accel_std_radps2: white angular-acceleration process noise.
        pos_std_m: detection position noise (one sigma, per axis).
        yaw_std_rad: detection heading noise.
        init_speed_std_mps: velocity uncertainty of a new track.
    """

    gate_m: float = 3.0
    birth_min_score: float = -np.inf
    birth_min_evidence: float = -np.inf
    t_birth_s: float = 0.2
    t_expire_s: float = 0.0
    t_prune_s: float = 0.3
    accel_std_mps2: float = 3.0
    yaw_accel_std_radps2: float = 2.0
    pos_std_m: float = 0.3
    yaw_std_rad: float = 0.3
    init_speed_std_mps: float = 5.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("birth_min_score", "birth_min_evidence"):
                if np.isnan(v):
                    raise ConfigError(f"ClassParams.{f.name}: expected a number, got NaN")
            elif not (np.isfinite(v) and v >= 0.0):
                raise ConfigError(f"ClassParams.{f.name}: expected a finite value >= 0, got {v!r}")
        if self.gate_m <= 0.0 or self.pos_std_m <= 0.0 or self.yaw_std_rad <= 0.0:
            raise ConfigError("ClassParams: expected gate_m, pos_std_m and yaw_std_rad > 0")
        if self.t_prune_s < self.t_expire_s:
            raise ConfigError(
                f"ClassParams.t_prune_s: expected >= t_expire_s ({self.t_expire_s}), got {self.t_prune_s}"
            )


def default_class_params() -> dict[int, ClassParams]:
    """Defaults per :class:`ObjectClass` (vehicles fast and large, pedestrians slow and small)."""
    # Times suit 10 Hz LiDAR: a car is full at its second detection, a pedestrian at its first (their
    # detections are sparse), and vulnerable road users coast through up to three missed frames.
    return {
        ObjectClass.UNKNOWN: ClassParams(),
        ObjectClass.CAR: ClassParams(
            gate_m=4.0,
            accel_std_mps2=4.0,
            yaw_accel_std_radps2=1.0,
            t_birth_s=0.1,
            t_expire_s=0.1,
            t_prune_s=0.3,
        ),
        ObjectClass.PEDESTRIAN: ClassParams(
            gate_m=2.0,
            accel_std_mps2=2.0,
            pos_std_m=0.2,
            yaw_std_rad=0.6,
            t_birth_s=0.0,
            t_expire_s=0.3,
            t_prune_s=0.4,
        ),
        ObjectClass.CYCLIST: ClassParams(
            gate_m=3.0,
            accel_std_mps2=3.0,
            yaw_accel_std_radps2=1.5,
            t_birth_s=0.2,
            t_expire_s=0.3,
            t_prune_s=0.4,
        ),
        ObjectClass.ANIMAL: ClassParams(
            gate_m=2.0, accel_std_mps2=3.0, pos_std_m=0.2, yaw_std_rad=0.8, t_expire_s=0.3, t_prune_s=0.4
        ),
    }


TRACK_SCORES = ("last", "evidence", "mean", "refined")
"""Choices of ``AutoTrackConfig.track_score``."""


@dataclass(frozen=True, slots=True, kw_only=True)
class AutoTrackConfig:
    """Tracker parameters (per-class ones in ``classes``, keyed by :class:`ObjectClass` value).

    Attributes:
        classes: per-class parameters; every ObjectClass must have an entry.
        association: cost weights and assignment method.
        hmm: class HMM.
        size_gain: weight of a new detection in the box size (exponential average), 0..1.
        radar_velocity_std_mps: noise of a radar Doppler velocity (over ground, per axis).
        track_score: what a published track's ``score`` is (before the coasting penalty): ``"last"``, its
            latest detection's score; ``"evidence"``, the sum of its detections' scores (read as
            log-odds of existence, the accumulated evidence, as ``birth_min_evidence`` reads them);
            ``"mean"``, their mean shrunk towards log-odds 0 by one prior detection; ``"refined"``, the
            score refinement of Benbarka et al. (IROS 2021, "multiplication"): each detection's score
            read as log-odds p, the track's confidence c <- 1 - (1 - c)(1 - p), published as log-odds
            (no parameter; unlike ``"evidence"`` a doubtful detection never lowers it).
        coast_score_penalty_per_s: a coasting full track's score drops by this per second undetected.
        rollback_window_s: how far back states are kept for replaying late messages.
        source_timeout_s: a source (sensor) silent for longer no longer holds back demotion and
            pruning (see "Lifecycle with several sources" in the module docstring).
        max_tracks: bound on live tracks (births beyond it are refused, counted in ``refused_births``).
    """

    classes: Mapping[int, ClassParams] = field(default_factory=default_class_params)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    hmm: ClassHmmConfig = field(default_factory=ClassHmmConfig)
    size_gain: float = 0.3
    radar_velocity_std_mps: float = 0.3
    track_score: str = "last"
    coast_score_penalty_per_s: float = 5.0
    rollback_window_s: float = 2.0
    source_timeout_s: float = 0.5
    max_tracks: int = 500

    def __post_init__(self) -> None:
        missing = [c.name for c in ObjectClass if int(c) not in self.classes]
        if missing:
            raise ConfigError(
                f"AutoTrackConfig.classes: expected an entry for every ObjectClass, missing {missing}"
            )
        if self.track_score not in TRACK_SCORES:
            raise ConfigError(
                f"AutoTrackConfig.track_score: expected one of {TRACK_SCORES}, got {self.track_score!r}"
            )
        if not 0.0 < self.size_gain <= 1.0:
            raise ConfigError(f"AutoTrackConfig.size_gain: expected in (0, 1], got {self.size_gain}")
        if (
            self.rollback_window_s < 0.0
            or self.source_timeout_s < 0.0
            or self.max_tracks < 1
            or self.radar_velocity_std_mps <= 0.0
        ):
            raise ConfigError(
                "AutoTrackConfig: expected rollback_window_s >= 0, source_timeout_s >= 0, max_tracks >= 1, "
                f"velocity std > 0, got {self.rollback_window_s}, {self.source_timeout_s}, "
                f"{self.max_tracks}, "
                f"{self.radar_velocity_std_mps}"
            )


def class_table(cfg: AutoTrackConfig) -> dict[str, np.ndarray]:
    names = [f.name for f in fields(ClassParams)]
    return {
        n: np.array([getattr(cfg.classes[int(c)], n) for c in ObjectClass], dtype=np.float64) for n in names
    }
