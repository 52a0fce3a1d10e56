"""Cross-validation over KITTI sequences: every sequence tracked with parameters chosen without its labels.

Given the results of several tracker candidates on every sequence, each fold's held-out sequences get,
per class, the results of the candidate that scores best on the *other* sequences, pooled (one KITTI 3D
MOT evaluation over all training sequences together, as the benchmark scores). The held-out labels are
never read while choosing (``tests/tracking/test_kitti_cv.py`` changes them and gets the same choice).

Ranking: sAMOTA first; ties broken by AMOTA, then MOTA (NaN, a class absent from the training
sequences, ranks last). sAMOTA is clipped at 0 per recall point, so a training pool whose false
positives outnumber its labelled objects scores 0 for every candidate; without the tie-break the choice
there would be the grid's first candidate, i.e. arbitrary. AMOTA is the same sweep unclipped.

With ``calibrate_scores``, each fold's held-out scores are the chosen candidate's track scores mapped to a
probability of being a true positive by a Platt map fitted on the fold's training sequences
(``runner.kitti_calibration``), so that folds tracked with different candidates are thresholded on one
scale by the pooled sweep.
"""

from __future__ import annotations

import math
import multiprocessing
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.evaluation.kitti_io import KittiRows
from lastmile.evaluation.kitti_mot import ClassResult, evaluate_class, row_outcomes
from lastmile.runner.kitti_calibration import PlattMap, calibrate, fit_on_training
from lastmile.runner.sweep import pin_blas_threads


def selection_key(result: ClassResult) -> tuple[float, float, float]:
    """Sort key of a candidate's pooled training score (larger is better; NaN ranks last)."""
    return tuple(v if math.isfinite(v) else -math.inf for v in (result.samota, result.amota, result.mota))  # type: ignore[return-value]


_STATE: dict[str, Any] = {}
"""The candidates' results, the labels and the frame counts, in this process or a worker (set once)."""


def _share(
    runs: Mapping[str, Mapping[str, KittiRows]], labels: Mapping[str, KittiRows], n_frames: Mapping[str, int]
) -> None:
    _STATE.update(runs=runs, labels=labels, n_frames=dict(n_frames))


def _training_key(name: str, train: tuple[str, ...], cls: str) -> tuple[float, float, float]:
    """``selection_key`` of candidate ``name`` on the pooled ``train`` sequences (reads ``_STATE``)."""
    runs, labels = _STATE["runs"], _STATE["labels"]
    result = evaluate_class(
        {s: labels[s] for s in train}, {s: runs[name][s] for s in train}, cls, n_frames=_STATE["n_frames"]
    )
    return selection_key(result)


def _training_keys(
    jobs: list[tuple[str, tuple[str, ...], str]], workers: int, on_evaluated: Callable[[], None] | None
) -> list[tuple[float, float, float]]:
    """``_training_key`` of every job, in a pool of forked workers when ``workers`` > 1."""

    def collect(results: Iterable[tuple[float, float, float]]) -> list[tuple[float, float, float]]:
        keys = []
        for key in results:  # in submission order: the choice does not depend on completion order
            keys.append(key)
            if on_evaluated is not None:
                on_evaluated()
        return keys

    if workers <= 1:
        return collect(_training_key(*job) for job in jobs)
    # Forked workers inherit _STATE: the candidates' rows (hundreds of MB for a large grid) are never
    # pickled, only the job names and the three floats each returns.
    ctx = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=pin_blas_threads) as pool:
        futures = [pool.submit(_training_key, *job) for job in jobs]
        return collect(f.result() for f in futures)


def two_folds(sequences: Sequence[str]) -> list[tuple[str, ...]]:
    """The first half of ``sequences`` and the second half (the held-out sets of a 2-fold CV)."""
    half = (len(sequences) + 1) // 2
    return [tuple(sequences[:half]), tuple(sequences[half:])]


def leave_one_out(sequences: Sequence[str]) -> list[tuple[str, ...]]:
    """One held-out set per sequence."""
    return [(s,) for s in sequences]


@dataclass(frozen=True, slots=True, kw_only=True)
class CrossValidation:
    """Held-out results and what was chosen.

    Attributes:
        held_out: per sequence, the rows of every class from the candidate chosen for its fold.
        chosen: per fold (its held-out sequences joined by ","), per class, the chosen candidate's name.
        training_scores: per fold, per class, per candidate, ``selection_key`` on the training pool.
        calibration: per fold, per class, the Platt map applied to the held-out scores (empty without
            ``calibrate_scores``).
    """

    held_out: dict[str, KittiRows]
    chosen: dict[str, dict[str, str]]
    training_scores: dict[str, dict[str, dict[str, tuple[float, float, float]]]]
    calibration: dict[str, dict[str, PlattMap]]


def _class_rows(rows: KittiRows, cls: str) -> KittiRows:
    return rows.select(np.array([str(t) == cls for t in rows.obj_type], dtype=bool))


def cross_validate(
    runs: Mapping[str, Mapping[str, KittiRows]],
    labels: Mapping[str, KittiRows],
    folds: Sequence[Sequence[str]],
    classes: Sequence[str],
    n_frames: Mapping[str, int],
    *,
    calibrate_scores: bool = False,
    workers: int = 1,
    on_evaluated: Callable[[], None] | None = None,
) -> CrossValidation:
    """Choose a candidate per fold and class on the other folds' labels; return the held-out results.

    Args:
        runs: per candidate name, per sequence, the tracker's results (all classes).
        labels: per sequence, the labels.
        folds: the held-out sets; together they must cover every labelled sequence exactly once.
        classes: KITTI class names to choose for ("Car", "Pedestrian", "Cyclist").
        n_frames: frames per sequence.
        calibrate_scores: map each fold's held-out scores through a Platt map fitted on its training
            sequences (see the module docstring).
        workers: processes for the pooled training evaluations (one per fold, class and candidate);
            the choices do not depend on it.
        on_evaluated: called after each training evaluation (a progress bar).

    Raises:
        ConfigError: no candidate, folds that do not partition the labelled sequences, or a candidate
            missing a sequence.
    """
    if not runs:
        raise ConfigError("cross_validate: expected at least one candidate, got none")
    seqs = list(labels)
    flat = [s for f in folds for s in f]
    if sorted(flat) != sorted(seqs):
        raise ConfigError(
            "cross_validate: expected folds partitioning the sequences "
            f"{sorted(seqs)}, got {list(map(list, folds))}"
        )
    for name, per_seq in runs.items():
        missing = [s for s in seqs if s not in per_seq]
        if missing:
            raise ConfigError(f"cross_validate: candidate {name!r} has no results for sequences {missing}")
    if workers < 1:
        raise ConfigError(f"cross_validate: expected workers >= 1, got {workers}")
    # Every (fold, class, candidate) training evaluation is independent: run them all, then choose.
    index = [(",".join(test), cls, name) for test in folds for cls in classes for name in runs]
    jobs = [
        (name, tuple(s for s in seqs if s not in test), cls)
        for test in folds
        for cls in classes
        for name in runs
    ]
    _share(runs, labels, n_frames)
    try:
        keys = dict(zip(index, _training_keys(jobs, workers, on_evaluated), strict=True))
    finally:
        _STATE.clear()  # the candidates' rows are not kept alive past this call
    held: dict[str, list[KittiRows]] = {s: [] for s in seqs}
    chosen: dict[str, dict[str, str]] = {}
    scores: dict[str, dict[str, dict[str, tuple[float, float, float]]]] = {}
    maps: dict[str, dict[str, PlattMap]] = {}
    for test in folds:
        train = [s for s in seqs if s not in test]
        key = ",".join(test)
        chosen[key], scores[key], maps[key] = {}, {}, {}
        train_labels = {s: labels[s] for s in train}  # the only labels this fold reads
        for cls in classes:
            per_cand = {name: keys[(key, cls, name)] for name in runs}  # grid order
            best = max(per_cand, key=lambda n: per_cand[n])  # first of equals: the grid's order
            chosen[key][cls], scores[key][cls] = best, per_cand
            out = {s: _class_rows(runs[best][s], cls) for s in test}
            if calibrate_scores:
                training = []
                for s in train:
                    rows = _class_rows(runs[best][s], cls)
                    training.append((rows, row_outcomes(train_labels[s], rows, cls, n_frames=n_frames[s])))
                maps[key][cls] = fit_on_training(training)
                out = {s: calibrate(r, maps[key][cls]) for s, r in out.items()}
            for s in test:
                held[s].append(out[s])
    return CrossValidation(
        held_out={s: KittiRows.concat(p) for s, p in held.items()},
        chosen=chosen,
        training_scores=scores,
        calibration=maps,
    )
