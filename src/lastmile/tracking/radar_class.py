"""Object class from a track's radar cross-section and speed, accumulated over the track's life."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass


@dataclass(frozen=True, slots=True, kw_only=True)
class RadarClassConfig:
    """How RCS and speed evidence map to a class.

    Radar cannot truly classify: a car's return is roughly +5..+15 dBsm, a pedestrian's or cyclist's
    -8..0 dBsm, a goose's -20..-12 dBsm. Each family is a Gaussian over the track's mean RCS; an
    "other" hypothesis with a flat density absorbs returns that fit none of them. Speed only rules
    families out (a fast object is no goose, a fast vulnerable road user is a cyclist).

    Attributes:
        car_rcs_dbsm, car_rcs_spread_db: mean and one-sigma spread of car RCS over cars and aspects.
        vru_rcs_dbsm, vru_rcs_spread_db: the same for pedestrians and cyclists (one family: radar
            cannot tell them apart by RCS).
        animal_rcs_dbsm, animal_rcs_spread_db: the same for geese, ducks and small dogs.
        rcs_noise_db: one-sigma frame-to-frame RCS scintillation; the mean of n hits has this over
            sqrt(n) on top of the family spread.
        other_prior: prior probability of "none of these" (clutter, poles, signs).
        other_rcs_window_db: width of the flat RCS density of "other".
        animal_max_speed_mps: fastest an ANIMAL track may ever have moved (geese walk, they do not run).
        pedestrian_max_speed_mps: a vulnerable road user that ever moved faster is a CYCLIST.
        cyclist_max_speed_mps: a low-RCS object faster than this is not a cyclist (UNKNOWN).
        min_probability: the best class is reported only above this posterior, else UNKNOWN.
    """

    car_rcs_dbsm: float = 10.0
    car_rcs_spread_db: float = 4.0
    vru_rcs_dbsm: float = -4.0
    vru_rcs_spread_db: float = 3.0
    animal_rcs_dbsm: float = -16.0
    animal_rcs_spread_db: float = 3.0
    rcs_noise_db: float = 3.0
    other_prior: float = 0.2
    other_rcs_window_db: float = 50.0
    animal_max_speed_mps: float = 1.5
    pedestrian_max_speed_mps: float = 3.0
    cyclist_max_speed_mps: float = 12.0
    min_probability: float = 0.8

    def __post_init__(self) -> None:
        for name in (
            "car_rcs_spread_db",
            "vru_rcs_spread_db",
            "animal_rcs_spread_db",
            "rcs_noise_db",
            "other_rcs_window_db",
            "animal_max_speed_mps",
        ):
            value = getattr(self, name)
            if not value > 0:
                raise ConfigError(f"RadarClassConfig.{name}: expected a positive number, got {value}")
        if not 0.0 <= self.other_prior < 1.0:
            raise ConfigError(
                f"RadarClassConfig.other_prior: expected a value in [0, 1), got {self.other_prior}"
            )
        if not 0.0 < self.min_probability <= 1.0:
            raise ConfigError(
                f"RadarClassConfig.min_probability: expected a value in (0, 1], got {self.min_probability}"
            )
        if not self.animal_max_speed_mps <= self.pedestrian_max_speed_mps <= self.cyclist_max_speed_mps:
            raise ConfigError(
                "RadarClassConfig: expected animal_max_speed_mps <= pedestrian_max_speed_mps <= "
                f"cyclist_max_speed_mps, got {self.animal_max_speed_mps}, {self.pedestrian_max_speed_mps}, "
                f"{self.cyclist_max_speed_mps}"
            )


_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
# Hypotheses in column order of the log-posterior matrix, and the class each reports.
_CAR, _VRU, _ANIMAL, _OTHER = 0, 1, 2, 3
_CLASS_OF_HYPOTHESIS = np.array(
    [ObjectClass.CAR, ObjectClass.PEDESTRIAN, ObjectClass.ANIMAL, ObjectClass.UNKNOWN], dtype=np.float64
)


def classify_radar_tracks(
    mean_rcs_dbsm: np.ndarray, hits: np.ndarray, max_speed_mps: np.ndarray, config: RadarClassConfig
) -> np.ndarray:
    """Class of each track from its accumulated evidence.

    Args:
        mean_rcs_dbsm: (T,) mean RCS over the track's hits, dBsm.
        hits: (T,) number of detections behind that mean (>= 1).
        max_speed_mps: (T,) fastest filtered speed the track has shown since it was confirmed, m/s.
        config: the class model.

    Returns:
        (T,) float64 :class:`ObjectClass` values (ready for the ``class_id`` column).
    """
    c = config
    means = np.array((c.car_rcs_dbsm, c.vru_rcs_dbsm, c.animal_rcs_dbsm))
    spreads = np.array((c.car_rcs_spread_db, c.vru_rcs_spread_db, c.animal_rcs_spread_db))
    var = spreads * spreads + (c.rcs_noise_db**2 / np.maximum(hits, 1.0))[:, None]
    log_post = np.empty((mean_rcs_dbsm.shape[0], 4))
    log_post[:, :3] = (
        math.log((1.0 - c.other_prior) / 3.0)
        - _HALF_LOG_2PI
        - 0.5 * ((mean_rcs_dbsm[:, None] - means) ** 2 / var + np.log(var))
    )
    log_post[:, _OTHER] = (
        math.log(c.other_prior) - math.log(c.other_rcs_window_db) if c.other_prior > 0 else -np.inf
    )
    # Speed is hard evidence: one confirmed fast stretch rules a family out for good.
    log_post[max_speed_mps > c.animal_max_speed_mps, _ANIMAL] = -np.inf
    log_post[max_speed_mps > c.cyclist_max_speed_mps, _VRU] = -np.inf
    best = log_post.argmax(axis=1)
    # The best hypothesis has weight 1 after subtracting its log-posterior: its probability is 1/sum.
    best_probability = 1.0 / np.exp(log_post - log_post[np.arange(len(best)), best][:, None]).sum(axis=1)
    cls = _CLASS_OF_HYPOTHESIS[best]
    cls[(best == _VRU) & (max_speed_mps > c.pedestrian_max_speed_mps)] = float(ObjectClass.CYCLIST)
    cls[best_probability < c.min_probability] = float(ObjectClass.UNKNOWN)
    return cls
