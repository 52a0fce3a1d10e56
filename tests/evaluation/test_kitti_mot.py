"""KITTI 3D MOT evaluator on hand-made sequences: every count is known in advance."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError, MessageError
from lastmile.evaluation.kitti_io import KittiRows, read_detections, read_labels, write_results
from lastmile.evaluation.kitti_mot import (
    ROW_FALSE,
    ROW_MATCHED,
    ROW_NOT_SCORED,
    ProtocolConfig,
    _switches,
    _thresholds,
    evaluate_class,
    row_outcomes,
)


def _rows(entries: list[tuple], with_score: bool = True) -> KittiRows:
    """entries: (frame, track_id, type, x, z, score[, truncation, occlusion, image_box])."""
    n = len(entries)
    frame = np.array([e[0] for e in entries], np.int64)
    tid = np.array([e[1] for e in entries], np.int64)
    cam = np.array([[1.5, 1.6, 3.9, e[3], 1.7, e[4], -np.pi / 2] for e in entries]).reshape(n, 7)
    img = np.array([e[8] if len(e) > 8 else (100.0, 100.0, 200.0, 200.0) for e in entries]).reshape(n, 4)
    return KittiRows(
        frame=frame,
        track_id=tid,
        obj_type=np.array([e[2] for e in entries], dtype=object),
        truncation=np.array([e[6] if len(e) > 6 else 0.0 for e in entries]),
        occlusion=np.array([e[7] if len(e) > 7 else 0 for e in entries], np.int64),
        alpha_rad=np.zeros(n),
        image_box=img,
        camera_box=cam,
        score=np.array([e[5] for e in entries]) if with_score else np.zeros(n),
    )


def _two_cars(frames: int = 5) -> KittiRows:
    return _rows(
        [(f, 0, "Car", 0.0, 10.0 + f, 0.0) for f in range(frames)]
        + [(f, 1, "Car", 5.0, 20.0, 0.0) for f in range(frames)]
    )


def test_perfect_tracks_score_one() -> None:
    gt = _two_cars(frames=40)  # 80 objects: enough true positives to sample all 40 recall points
    res = _rows([(int(f), int(t) + 7, "Car", x, z, 5.0) for f, t, x, z in _entries(gt)])
    r = evaluate_class({"s": gt}, {"s": res}, "Car")
    assert (r.mota, r.samota, r.amota) == (1.0, 1.0, 1.0)
    assert r.motp == pytest.approx(1.0)
    assert (r.fp, r.fn, r.id_switches, r.fragmentations, r.tp, r.n_gt) == (0, 0, 0, 0, 80, 80)


def test_few_objects_sample_fewer_recall_points_as_the_reference_does() -> None:
    # 10 true positives give 9 usable thresholds: sAMOTA = 9 / 40 even for perfect tracks.
    gt = _two_cars()
    res = _rows([(int(f), int(t) + 7, "Car", x, z, 5.0) for f, t, x, z in _entries(gt)])
    r = evaluate_class({"s": gt}, {"s": res}, "Car")
    assert r.mota == 1.0 and r.samota == pytest.approx(9 / 40)


def _entries(rows: KittiRows) -> list[tuple[int, int, float, float]]:
    return [
        (
            int(rows.frame[i]),
            int(rows.track_id[i]),
            float(rows.camera_box[i, 3]),
            float(rows.camera_box[i, 5]),
        )
        for i in range(len(rows))
    ]


def test_one_id_switch_is_counted_once() -> None:
    gt = _two_cars()
    # Object 0 is output as track 10 for frames 0-2 and as track 11 from frame 3 on.
    res = _rows(
        [(f, 10 if f < 3 else 11, "Car", 0.0, 10.0 + f, 5.0) for f in range(5)]
        + [(f, 20, "Car", 5.0, 20.0, 5.0) for f in range(5)]
    )
    r = evaluate_class({"s": gt}, {"s": res}, "Car")
    assert r.id_switches == 1
    assert r.mota == pytest.approx(1.0 - 1.0 / 10.0)
    assert (r.fp, r.fn) == (0, 0)


def test_one_false_positive_and_one_miss() -> None:
    gt = _two_cars()
    res = _rows(
        [(f, 10, "Car", 0.0, 10.0 + f, 5.0) for f in range(5)]
        + [(f, 20, "Car", 5.0, 20.0, 5.0) for f in range(4)]  # misses object 1 in frame 4
        + [(2, 30, "Car", -8.0, 40.0, 5.0)]  # nothing there
    )
    r = evaluate_class({"s": gt}, {"s": res}, "Car")
    # The ghost track 30 has the same mean score as the others, so no threshold removes it alone.
    assert (r.fp, r.fn, r.id_switches) == (1, 1, 0)
    assert r.mota == pytest.approx(1.0 - 2.0 / 10.0)


def test_identical_boxes_in_results_and_labels_do_not_break_the_overlap() -> None:
    gt = _rows([(0, 0, "Car", 1.0, 10.0, 0.0), (0, 1, "Car", 1.0, 10.0, 0.0)])
    res = _rows([(0, 5, "Car", 1.0, 10.0, 1.0), (0, 6, "Car", 1.0, 10.0, 1.0)])
    r = evaluate_class({"s": gt}, {"s": res}, "Car")
    assert (r.tp, r.fp, r.fn, r.mota) == (2, 0, 0, 1.0)


def test_empty_frames_and_a_sequence_without_the_class() -> None:
    gt = {"a": _rows([(0, 0, "Car", 0.0, 10.0, 0.0), (4, 0, "Car", 0.0, 10.0, 0.0)]), "b": _rows([])}
    res = {"a": _rows([(0, 1, "Car", 0.0, 10.0, 2.0), (4, 1, "Car", 0.0, 10.0, 2.0)])}
    r = evaluate_class(gt, res, "Car", n_frames={"a": 8, "b": 3})
    assert (r.tp, r.fn, r.fp, r.mota) == (2, 0, 0, 1.0)
    none = evaluate_class(gt, res, "Cyclist")
    assert math.isnan(none.samota) and math.isnan(none.mota) and none.n_gt == 0
    assert none.as_dict()["samota"] is None


DONTCARE_BOX = (500.0, 100.0, 600.0, 200.0)
INSIDE_DONTCARE = (510.0, 110.0, 590.0, 190.0)


def _car_dontcare_and_van(van_frame: int) -> KittiRows:
    """Labels: a car in frames 0 and ``van_frame``, a DontCare region in frame 0, a van in ``van_frame``."""
    entries: list[tuple] = [
        (0, 0, "Car", 0.0, 10.0, 0.0),
        (0, -1, "DontCare", 0.0, 0.0, 0.0, 0.0, 0, DONTCARE_BOX),
        (van_frame, 3, "Van", 9.0, 30.0, 0.0),
    ]
    return _rows(entries if van_frame == 0 else [*entries, (van_frame, 0, "Car", 0.0, 10.0, 0.0)])


def test_dontcare_small_and_neighbour_class_outputs_are_ignored_not_false_positives() -> None:
    gt = _car_dontcare_and_van(van_frame=0)
    res = _rows(
        [
            (0, 1, "Car", 0.0, 10.0, 2.0),
            (0, 2, "Car", -9.0, 50.0, 2.0, 0, 0, INSIDE_DONTCARE),
            (0, 4, "Car", 9.0, 60.0, 2.0, 0, 0, (100.0, 100.0, 200.0, 110.0)),  # 10 px high
            (0, 5, "Car", 9.0, 30.0, 2.0),  # on the van: ignored TP, not counted
        ]
    )
    r = evaluate_class({"s": gt}, {"s": res}, "Car")
    assert (r.fp, r.fn, r.n_gt) == (0, 0, 1)
    assert r.mota == 1.0


def test_row_outcomes_say_which_rows_the_protocol_counts_as_true_false_or_not_at_all() -> None:
    gt = _car_dontcare_and_van(van_frame=1)
    res = _rows(
        [
            (1, 1, "Car", 0.0, 10.0, 2.0),  # matched (rows need not be in frame order)
            (1, 6, "Car", 9.0, 30.0, 2.0),  # on the van: a true positive the evaluator does not count missed
            (0, 1, "Car", 0.0, 10.0, 2.0),  # matched
            (0, 2, "Car", -9.0, 50.0, 2.0, 0, 0, INSIDE_DONTCARE),  # inside DontCare
            (0, 3, "Car", 9.0, 40.0, 2.0),  # nothing there: a false positive
            (0, 4, "Pedestrian", 0.0, 10.0, 2.0),  # another class
            (1, 5, "Car", 0.0, 10.0, 2.0),  # the car's second track in frame 1: Hungarian leaves it false
            (2, 1, "Car", 0.0, 10.0, 2.0),  # beyond n_frames
        ]
    )
    out = row_outcomes(gt, res, "Car", n_frames=2)
    m, f, n = ROW_MATCHED, ROW_FALSE, ROW_NOT_SCORED
    np.testing.assert_array_equal(out, [m, m, m, n, f, n, f, n])
    # The counts agree with the evaluator's at its no-threshold pass.
    r = evaluate_class({"s": gt}, {"s": res}, "Car", n_frames={"s": 2})
    assert (r.tp, r.fp) == (int(np.sum(out == m)), int(np.sum(out == f)))


def test_truncated_and_occluded_ground_truth_is_not_a_miss() -> None:
    gt = _rows([(0, 0, "Car", 0.0, 10.0, 0.0, 1.0, 0), (0, 1, "Car", 5.0, 20.0, 0.0, 0.0, 3)])
    r = evaluate_class({"s": gt}, {}, "Car")
    assert (r.fn, r.n_gt) == (0, 0)


def test_trajectory_rules_for_switches_and_fragments() -> None:
    assert _switches([1, 1, 2, 2], [False] * 4) == (1, 1)
    assert _switches([1, -1, 1, 1], [False] * 4) == (0, 1)
    assert _switches([1, -1, 2, 2], [False] * 4) == (0, 1)  # devkit: no IDS across a gap
    assert _switches([-1, -1], [False, False]) == (0, 0)


def test_thresholds_sample_recall_in_fortieths() -> None:
    scores = list(np.linspace(1.0, 0.0, 80))
    thr, rec = _thresholds(scores, 80)
    assert len(thr) == 40 and rec[0] == pytest.approx(1 / 40) and rec[-1] == pytest.approx(1.0)
    assert thr == sorted(thr, reverse=True)
    assert _thresholds([], 0) == ([], [])


def test_files_round_trip_and_bad_lines_raise(tmp_path: Path) -> None:
    rows = _rows([(0, 3, "Car", 1.0, 10.0, 0.5), (2, 4, "Cyclist", -1.0, 12.0, 0.25)])
    write_results(tmp_path / "0001.txt", rows)
    back = read_labels(tmp_path / "0001.txt", with_score=True)
    assert back.track_id.tolist() == [3, 4] and np.allclose(back.camera_box, rows.camera_box, atol=1e-4)
    assert np.allclose(back.score, [0.5, 0.25])
    (tmp_path / "bad.txt").write_text("0 1 Car 0 0\n")
    with pytest.raises(MessageError, match=r"bad.txt:1: expected 17 fields, got 5"):
        read_labels(tmp_path / "bad.txt")
    (tmp_path / "det.txt").write_text("0,7," + ",".join(["1"] * 13) + "\n")
    with pytest.raises(MessageError, match="expected type 1, 2 or 3"):
        read_detections(tmp_path / "det.txt")
    with pytest.raises(ConfigError, match="missing"):
        read_detections(tmp_path / "nope.txt")


def test_results_files_round_trip_bit_for_bit(tmp_path: Path) -> None:
    rows = _rows([(0, 3, "Car", 1.0 / 3.0, 10.1, 2.0 / 7.0)])
    write_results(tmp_path / "r.txt", rows)
    back = read_labels(tmp_path / "r.txt", with_score=True)
    assert back.score[0] == rows.score[0] and np.array_equal(back.camera_box, rows.camera_box)


def test_reference_score_rounding_can_drop_the_only_track_and_exact_means_do_not() -> None:
    # Scores whose mean, re-averaged from n copies, falls one rounding step lower (found by search).
    scores = [3.66, 1.06, 0.41, 0.25, 4.82, 0.75]
    mean = sum(scores) / 6.0
    assert sum([mean] * 6) / 6.0 < mean
    gt = _rows([(f, 0, "Car", 0.0, 10.0, 0.0) for f in range(6)])
    res = _rows([(f, 1, "Car", 0.0, 10.0, scores[f]) for f in range(6)])
    quirky = evaluate_class({"s": gt}, {"s": res}, "Car")
    no_quirk = ProtocolConfig(reference_score_rounding=False)
    exact = evaluate_class({"s": gt}, {"s": res}, "Car", config=no_quirk)
    assert quirky.samota == pytest.approx(0.0, abs=1e-9) and exact.samota == pytest.approx(5 / 40)


def _with_camera_box(rows: KittiRows, index: int, camera_box: tuple[float, ...]) -> KittiRows:
    cam = rows.camera_box.copy()
    cam[index] = camera_box
    return KittiRows(**{**{f: getattr(rows, f) for f in KittiRows.__slots__}, "camera_box": cam})  # type: ignore[attr-defined]


def test_a_zero_volume_result_box_on_a_labelled_car_is_a_miss_and_a_false_positive_not_a_nan() -> None:
    gt = _rows([(0, 0, "Car", 1.0, 10.0, 0.0), (1, 0, "Car", 1.0, 11.0, 0.0)])
    res = _rows([(0, 5, "Car", 1.0, 10.0, 1.0), (1, 5, "Car", 1.0, 11.0, 1.0)])
    flat = _with_camera_box(res, 1, (0.0, 0.0, 0.0, 1.0, 1.7, 11.0, -np.pi / 2))  # h = w = l = 0
    r = evaluate_class({"s": gt}, {"s": flat}, "Car")
    assert (r.tp, r.fn, r.fp) == (1, 1, 1)
    assert math.isfinite(r.mota) and math.isfinite(r.motp) and math.isfinite(r.samota)


def test_a_zero_volume_labelled_box_matches_nothing_even_an_identical_zero_volume_result() -> None:
    flat = (0.0, 0.0, 0.0, 1.0, 1.7, 10.0, -np.pi / 2)
    gt = _with_camera_box(_rows([(0, 0, "Car", 1.0, 10.0, 0.0)]), 0, flat)
    res = _with_camera_box(_rows([(0, 3, "Car", 1.0, 10.0, 1.0)]), 0, flat)
    r = evaluate_class({"s": gt}, {"s": res}, "Car")
    assert (r.tp, r.fn, r.fp) == (0, 1, 1)
    assert math.isfinite(r.mota)


def test_two_tracks_with_identical_boxes_on_one_car_give_one_match_and_one_false_positive() -> None:
    gt = _rows([(f, 0, "Car", 1.0, 10.0 + f, 0.0) for f in range(3)])
    res = _rows([(f, t, "Car", 1.0, 10.0 + f, 1.0) for f in range(3) for t in (4, 9)])
    r = evaluate_class({"s": gt}, {"s": res}, "Car")
    assert (r.tp, r.fn, r.fp, r.id_switches) == (3, 0, 3, 0)
    assert r.mota == pytest.approx(0.0)


def test_no_results_at_all_for_a_labelled_sequence_counts_every_object_missed() -> None:
    gt = _two_cars()
    for res in ({}, {"s": KittiRows.empty()}):
        r = evaluate_class({"s": gt}, res, "Car")
        assert (r.tp, r.fn, r.fp, r.n_gt) == (0, 10, 0, 10)
        assert (r.mota, r.samota, r.amota) == (0.0, 0.0, 0.0)


def test_results_for_a_class_the_labels_lack_are_false_positives_and_scores_are_nan() -> None:
    gt = _two_cars()
    res = _rows([(0, 1, "Cyclist", 0.0, 10.0, 2.0), (1, 1, "Cyclist", 0.0, 11.0, 2.0)])
    r = evaluate_class({"s": gt}, {"s": res}, "Cyclist")
    assert (r.n_gt, r.tp, r.fp) == (0, 0, 2)
    assert math.isnan(r.samota) and math.isnan(r.amota) and math.isnan(r.motp)


def test_labels_and_results_both_empty_score_nan_without_error(tmp_path: Path) -> None:
    write_results(tmp_path / "0000.txt", KittiRows.empty())
    res = read_labels(tmp_path / "0000.txt", with_score=True)
    assert len(res) == 0 and (tmp_path / "0000.txt").read_text() == ""
    for cls in ("Car", "Pedestrian", "Cyclist"):
        r = evaluate_class({"s": KittiRows.empty()}, {"s": res}, cls, n_frames={"s": 5})
        assert (r.tp, r.fp, r.fn, r.n_gt, r.id_switches) == (0, 0, 0, 0, 0)
        assert math.isnan(r.samota) and math.isnan(r.mota)
