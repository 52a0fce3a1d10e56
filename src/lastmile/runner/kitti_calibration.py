"""Track scores on one scale across folds: Platt scaling fitted on a fold's training sequences.

Why: the KITTI sAMOTA sweep thresholds the scores of every sequence together, so when a
cross-validation tracks its folds with different candidates (different lifecycles, or different track
score definitions, whose scales differ by orders of magnitude: a mean log-odds against a sum of them)
the pooled sweep compares numbers that do not mean the same. Mapping each fold's scores to the
probability that a row is a true positive, learnt on that fold's *training* sequences only, puts every
fold on one scale. The map is increasing, so it never reorders one fold's tracks.

What is mapped: each track's mean score, the quantity the KITTI evaluator thresholds (it overwrites
every row with its track's mean). The calibrated probability is written on every row of the track as a
multiple of 2**-20, so any evaluator re-averaging those equal rows gets the value back exactly: the
standard evaluator's re-averaging quirk (``ProtocolConfig.reference_score_rounding``) cannot remove a
track.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize

from lastmile.core.errors import ConfigError
from lastmile.evaluation.kitti_io import KittiRows
from lastmile.evaluation.kitti_mot import ROW_FALSE, ROW_MATCHED

SCORE_GRID = 2.0**-20
"""Calibrated scores are multiples of this: sums of a few million equal ones stay exact in float64."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PlattMap:
    """P(true positive) = 1 / (1 + exp(-(slope * (score - centre) / scale + offset))).

    ``n_matched`` / ``n_false``: the training rows it was fitted on (rows the protocol ignores are left
    out). ``slope`` is >= 0: a score can be uninformative on a training pool, never trusted backwards.
    """

    slope: float
    offset: float
    centre: float
    scale: float
    n_matched: int
    n_false: int

    def __call__(self, score: np.ndarray) -> np.ndarray:
        z = self.slope * (np.asarray(score, dtype=np.float64) - self.centre) / self.scale + self.offset
        return 0.5 * (1.0 + np.tanh(0.5 * z))  # the logistic function, without overflow


def track_mean_scores(rows: KittiRows) -> np.ndarray:
    """Per row, the mean score of its track (a track: one id and one class in one sequence)."""
    if len(rows) == 0:
        return np.zeros(0)
    keys = np.array([f"{t}\0{c}" for t, c in zip(rows.track_id, rows.obj_type, strict=True)])
    _, track = np.unique(keys, return_inverse=True)
    total = np.bincount(track, weights=rows.score)
    count = np.bincount(track)
    return (total / count)[track]


def fit_platt(scores: np.ndarray, outcomes: np.ndarray) -> PlattMap:
    """Fit the map on training rows: their track mean ``scores`` and protocol ``outcomes``.

    Platt's smoothed targets ((N+ + 1) / (N+ + 2) for matched rows, 1 / (N- + 2) for false ones) keep the
    fit finite when the training pool separates perfectly or holds one outcome only.

    Raises:
        ConfigError: no scored row (nothing to learn a scale from), or a non-finite score.
    """
    s = np.asarray(scores, dtype=np.float64)
    o = np.asarray(outcomes)
    if s.shape != o.shape:
        raise ConfigError(
            f"fit_platt: expected scores and outcomes of one shape, got {s.shape} and {o.shape}"
        )
    used = (o == ROW_MATCHED) | (o == ROW_FALSE)
    s, pos = s[used], o[used] == ROW_MATCHED
    if s.size == 0:
        raise ConfigError("fit_platt: expected at least one matched or false-positive training row, got none")
    if not np.all(np.isfinite(s)):
        raise ConfigError("fit_platt: expected finite track scores, got NaN or infinity")
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    target = np.where(pos, (n_pos + 1.0) / (n_pos + 2.0), 1.0 / (n_neg + 2.0))
    centre = float(s.mean())
    scale = float(s.std()) or 1.0
    z = (s - centre) / scale

    def loss(p: np.ndarray) -> tuple[float, np.ndarray]:
        u = p[0] * z + p[1]
        # Cross-entropy with soft targets: log(1 + e^u) - t u, computed stably.
        value = float(np.sum(np.logaddexp(0.0, u) - target * u))
        g = 0.5 * (1.0 + np.tanh(0.5 * u)) - target
        return value, np.array([float(np.sum(g * z)), float(np.sum(g))])

    bounds = [(0.0, None), (None, None)]
    res = minimize(loss, np.array([1.0, 0.0]), jac=True, method="L-BFGS-B", bounds=bounds)
    return PlattMap(
        slope=float(res.x[0]),
        offset=float(res.x[1]),
        centre=centre,
        scale=scale,
        n_matched=n_pos,
        n_false=n_neg,
    )


def fit_on_training(parts: Sequence[tuple[KittiRows, np.ndarray]]) -> PlattMap:
    """Fit on several training sequences: (one class's result rows, their ``row_outcomes``) each."""
    scores = [track_mean_scores(rows) for rows, _ in parts]
    outcomes = [o for _, o in parts]
    return fit_platt(
        np.concatenate(scores) if scores else np.zeros(0),
        np.concatenate(outcomes) if outcomes else np.zeros(0, np.int8),
    )


def calibrate(rows: KittiRows, mapping: PlattMap) -> KittiRows:
    """``rows`` with every row's score its track's calibrated mean, on the ``SCORE_GRID``."""
    p = mapping(track_mean_scores(rows))
    return replace(rows, score=np.round(p / SCORE_GRID) * SCORE_GRID)
