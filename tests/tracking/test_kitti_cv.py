"""Cross-validation over KITTI sequences: choices never read the held-out labels; ties are broken."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.evaluation.kitti_io import KittiRows
from lastmile.evaluation.kitti_mot import ClassResult
from lastmile.runner.kitti_cv import cross_validate, leave_one_out, selection_key, two_folds
from tests.tracking.kitti_car import car_rows

FRAMES = 30


def _car(x: float, track_id: int, score: float = 5.0) -> KittiRows:
    return car_rows(x, track_id, score, FRAMES)


SEQS = ("a", "b", "c")
LABELS = {s: _car(0.0, 1, score=0.0) for s in SEQS}
N_FRAMES = dict.fromkeys(SEQS, FRAMES)
# "on" tracks the labelled car; "off" reports it 6 m to the side (all misses and false positives).
RUNS = {"off": {s: _car(6.0, 7) for s in SEQS}, "on": {s: _car(0.0, 7) for s in SEQS}}


def _result(samota: float, amota: float, mota: float) -> ClassResult:
    return ClassResult(
        samota=samota, amota=amota, amotp=0.0, mota=mota, motp=0.0, id_switches=0,
        fragmentations=0, fp=0, fn=0, tp=0, n_gt=0, best_threshold=0.0,
    )  # fmt: skip


def test_candidates_tied_at_zero_samota_are_ranked_by_amota_then_mota_and_nan_ranks_last() -> None:
    clipped = _result(0.0, -0.2, -1.0)
    worse = _result(0.0, -0.5, 0.5)
    assert selection_key(clipped) > selection_key(worse)
    assert selection_key(_result(0.0, -0.2, -0.9)) > selection_key(clipped)
    assert selection_key(_result(0.1, -3.0, -9.0)) > selection_key(clipped)
    assert selection_key(_result(math.nan, math.nan, math.nan)) < selection_key(worse)


def test_each_fold_uses_the_candidate_best_on_the_other_sequences() -> None:
    cv = cross_validate(RUNS, LABELS, leave_one_out(SEQS), ["Car"], N_FRAMES)
    assert all(c["Car"] == "on" for c in cv.chosen.values())
    assert set(cv.chosen) == set(SEQS)
    for s in SEQS:
        np.testing.assert_array_equal(cv.held_out[s].camera_box, RUNS["on"][s].camera_box)


def test_changing_the_held_out_sequences_labels_does_not_change_its_choice() -> None:
    # Sequence c relabelled with the car where "off" reports it: the choices for a and b (trained on c)
    # change, the choice for c itself (trained on a and b) cannot.
    moved = {**LABELS, "c": _car(6.0, 1, score=0.0)}
    honest = cross_validate(RUNS, LABELS, leave_one_out(SEQS), ["Car"], N_FRAMES)
    poisoned = cross_validate(RUNS, moved, leave_one_out(SEQS), ["Car"], N_FRAMES)
    assert poisoned.chosen["c"] == honest.chosen["c"]
    assert poisoned.training_scores["c"] == honest.training_scores["c"]
    assert poisoned.training_scores["a"] != honest.training_scores["a"]
    np.testing.assert_array_equal(poisoned.held_out["c"].camera_box, honest.held_out["c"].camera_box)


def test_folds_must_partition_the_sequences_and_candidates_must_cover_them() -> None:
    assert two_folds(["0", "1", "2", "3", "4"]) == [("0", "1", "2"), ("3", "4")]
    with pytest.raises(ConfigError, match="partitioning"):
        cross_validate(RUNS, LABELS, [("a",), ("b",)], ["Car"], N_FRAMES)
    with pytest.raises(ConfigError, match=r"'short'.*'c'"):
        cross_validate({"short": {"a": RUNS["on"]["a"]}}, LABELS, [("a", "b", "c")], ["Car"], N_FRAMES)
    with pytest.raises(ConfigError, match="at least one candidate"):
        cross_validate({}, LABELS, [("a", "b", "c")], ["Car"], N_FRAMES)


def test_training_evaluations_in_worker_processes_choose_exactly_as_in_one() -> None:
    one = cross_validate(RUNS, LABELS, leave_one_out(SEQS), ["Car"], N_FRAMES, calibrate_scores=True)
    calls: list[int] = []
    two = cross_validate(
        RUNS,
        LABELS,
        leave_one_out(SEQS),
        ["Car"],
        N_FRAMES,
        calibrate_scores=True,
        workers=2,
        on_evaluated=lambda: calls.append(1),
    )
    assert len(calls) == len(RUNS) * len(SEQS)
    assert two.chosen == one.chosen and two.training_scores == one.training_scores
    assert two.calibration == one.calibration
    for s in SEQS:
        np.testing.assert_array_equal(two.held_out[s].score, one.held_out[s].score)
    with pytest.raises(ConfigError, match="workers >= 1"):
        cross_validate(RUNS, LABELS, leave_one_out(SEQS), ["Car"], N_FRAMES, workers=0)
