"""Score calibration for the KITTI cross-validation: one scale across folds, learnt on training labels."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.evaluation.kitti_io import KittiRows
from lastmile.evaluation.kitti_mot import (
    ROW_FALSE,
    ROW_MATCHED,
    ROW_NOT_SCORED,
    ProtocolConfig,
    evaluate_class,
)
from lastmile.runner.kitti_calibration import SCORE_GRID, calibrate, fit_platt, track_mean_scores
from lastmile.runner.kitti_cv import cross_validate
from tests.tracking.kitti_car import car_rows

FRAMES = 30


def _car(x: float, track_id: int, scores: list[float] | float, frames: int = FRAMES) -> KittiRows:
    return car_rows(x, track_id, scores, frames)


def _concat(*parts: KittiRows) -> KittiRows:
    return KittiRows.concat(parts)


def test_higher_scores_that_are_more_often_right_map_to_higher_probabilities() -> None:
    rng = np.random.default_rng(0)
    scores = rng.uniform(-3.0, 3.0, 4000)
    right = rng.random(4000) < 1.0 / (1.0 + np.exp(-2.0 * scores))
    m = fit_platt(scores, np.where(right, ROW_MATCHED, ROW_FALSE).astype(np.int8))
    p = m(np.array([-3.0, -1.0, 0.0, 1.0, 3.0]))
    assert np.all(np.diff(p) > 0)
    # The data came from P = sigmoid(2 s): the fit recovers it to a few hundredths.
    truth = 1.0 / (1.0 + np.exp(-2.0 * np.array([-3.0, -1.0, 0.0, 1.0, 3.0])))
    np.testing.assert_allclose(p, truth, atol=0.04)
    assert (m.n_matched, m.n_false) == (int(right.sum()), int((~right).sum()))


def test_a_perfectly_separating_score_gets_a_finite_map_and_ignored_rows_are_left_out() -> None:
    scores = np.array([1.0, 1.0, 5.0, 5.0, 100.0])
    outcomes = np.array([ROW_FALSE, ROW_FALSE, ROW_MATCHED, ROW_MATCHED, ROW_NOT_SCORED], np.int8)
    m = fit_platt(scores, outcomes)
    assert np.isfinite(m.slope) and m.slope > 0
    assert (m.n_matched, m.n_false) == (2, 2)
    # Platt's smoothed targets: never certainty from four rows.
    assert 0.5 < m(np.array([5.0]))[0] < 1.0 and 0.0 < m(np.array([1.0]))[0] < 0.5


def test_a_score_that_is_right_backwards_is_not_trusted_backwards() -> None:
    scores = np.array([1.0, 1.0, 5.0, 5.0])
    outcomes = np.array([ROW_MATCHED, ROW_MATCHED, ROW_FALSE, ROW_FALSE], np.int8)
    m = fit_platt(scores, outcomes)
    assert m.slope == 0.0
    assert m(np.array([1.0]))[0] == m(np.array([5.0]))[0]


def test_bad_training_data_is_refused_with_what_was_expected() -> None:
    with pytest.raises(ConfigError, match="at least one matched or false-positive"):
        fit_platt(np.array([1.0]), np.array([ROW_NOT_SCORED], np.int8))
    with pytest.raises(ConfigError, match="finite"):
        fit_platt(np.array([np.nan]), np.array([ROW_MATCHED], np.int8))
    with pytest.raises(ConfigError, match="one shape"):
        fit_platt(np.array([1.0, 2.0]), np.array([ROW_MATCHED], np.int8))


def test_calibrated_rows_hold_their_tracks_probability_on_a_grid_the_evaluator_re_averages_exactly() -> None:
    # Scores whose mean, re-averaged from six copies, falls one rounding step lower: the standard
    # evaluator drops this track at its own threshold (tests/evaluation/test_kitti_mot.py).
    quirky = [3.66, 1.06, 0.41, 0.25, 4.82, 0.75]
    rows = _concat(_car(0.0, 1, quirky, frames=6), _car(6.0, 2, 0.5, frames=6))
    np.testing.assert_allclose(track_mean_scores(rows)[:6], sum(quirky) / 6.0)
    m = fit_platt(np.array([0.0, 2.0]), np.array([ROW_FALSE, ROW_MATCHED], np.int8))
    cal = calibrate(rows, m)
    first, second = cal.score[:6], cal.score[6:]
    assert np.all(first == first[0]) and np.all(second == second[0]) and first[0] > second[0]
    assert np.all(cal.score / SCORE_GRID == np.round(cal.score / SCORE_GRID))
    assert sum([float(first[0])] * 6) / 6.0 == first[0]
    gt = _car(0.0, 0, 0.0, frames=6)
    standard = evaluate_class({"s": gt}, {"s": cal}, "Car")
    no_quirk = ProtocolConfig(reference_score_rounding=False)
    exact = evaluate_class({"s": gt}, {"s": cal}, "Car", config=no_quirk)
    assert standard.samota == exact.samota == pytest.approx(5 / 40)


def test_folds_on_two_scales_are_pooled_on_one_after_calibration_without_reading_held_out_labels() -> None:
    # Every sequence has a right track and a wrong one, the right one scoring higher. "big" scores 100
    # times higher than "small"; each loses half of the car on the sequences the other is best on, so
    # the fold holding out "a" (trained on b, c) chooses "big" and the other fold "small". Raw, a's
    # wrong track out-ranks the right tracks of b and c in the pooled sweep; calibrated, it does not.
    labels = {s: _car(0.0, 1, 0.0) for s in "abc"}
    n_frames = dict.fromkeys("abc", FRAMES)
    folds = [("a",), ("b", "c")]

    def seq(scale: float, right_frames: int) -> KittiRows:
        return _concat(_car(0.0, 7, 3.0 * scale, frames=right_frames), _car(6.0, 8, 1.0 * scale))

    half = FRAMES // 2
    runs = {
        "big": {"a": seq(100.0, half), "b": seq(100.0, FRAMES), "c": seq(100.0, FRAMES)},
        "small": {"a": seq(1.0, FRAMES), "b": seq(1.0, half), "c": seq(1.0, half)},
    }
    cv = cross_validate(runs, labels, folds, ["Car"], n_frames, calibrate_scores=True)
    raw = cross_validate(runs, labels, folds, ["Car"], n_frames)
    assert cv.chosen == raw.chosen == {"a": {"Car": "big"}, "b,c": {"Car": "small"}}
    assert set(cv.calibration) == {"a", "b,c"} and not any(raw.calibration.values())

    def right_and_wrong(held: dict[str, KittiRows], s: str) -> tuple[np.ndarray, np.ndarray]:
        rows = held[s]
        on = rows.camera_box[:, 3] == 0.0
        return rows.score[on], rows.score[~on]

    assert right_and_wrong(raw.held_out, "a")[1].min() > right_and_wrong(raw.held_out, "b")[0].max()
    rights = np.concatenate([right_and_wrong(cv.held_out, s)[0] for s in "abc"])
    wrongs = np.concatenate([right_and_wrong(cv.held_out, s)[1] for s in "abc"])
    assert rights.min() > wrongs.max()
    pooled_cal = evaluate_class(labels, cv.held_out, "Car", n_frames=n_frames)
    pooled_raw = evaluate_class(labels, raw.held_out, "Car", n_frames=n_frames)
    assert pooled_cal.samota > pooled_raw.samota
    # The held-out sequence's labels are never read: moving its car changes nothing for its fold.
    poisoned = {**labels, "a": _car(6.0, 1, 0.0)}
    cv2 = cross_validate(runs, poisoned, folds, ["Car"], n_frames, calibrate_scores=True)
    assert cv2.calibration["a"] == cv.calibration["a"]
    np.testing.assert_array_equal(cv2.held_out["a"].score, cv.held_out["a"].score)
