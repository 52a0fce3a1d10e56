"""`lastmile eval tracking` on real KITTI data (skipped without ../shared/data) and on bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lastmile.cli import app

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "kitti_tracking"


@pytest.mark.skipif(not DATA.is_dir(), reason=f"KITTI tracking data not found at {DATA}")
def test_eval_tracking_scores_a_real_sequence_and_writes_results(tmp_path: Path) -> None:
    out = tmp_path / "scores.json"
    res = tmp_path / "results"
    result = CliRunner().invoke(
        app,
        [
            "eval",
            "tracking",
            "--detections",
            str(DATA / "detections"),
            "--labels",
            str(DATA / "labels"),
            "--sequences",
            "0000",
            "--json",
            str(out),
            "--results",
            str(res),
        ],
    )
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    assert report["frames"] == 154 and report["frames_per_second"] > 0
    for cls in ("Car", "Pedestrian", "Cyclist"):
        assert set(report[cls]) == {
            "samota",
            "amota",
            "mota",
            "motp",
            "id_switches",
            "fragmentations",
            "fp",
            "fn",
        }
    # AB3DMOT on the same detections scores Car MOTA 0.772 with 0 ID switches on this sequence.
    assert report["Car"]["mota"] > 0.78 and report["Car"]["id_switches"] == 0
    lines = (res / "0000.txt").read_text().splitlines()
    assert lines and all(len(line.split()) == 18 for line in lines)


def test_eval_tracking_reports_a_missing_directory_in_one_line(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app, ["eval", "tracking", "--detections", str(tmp_path / "nope"), "--labels", str(tmp_path)]
    )
    assert result.exit_code == 2
    assert "expected <seq>.txt files" in result.output and len(result.output.strip().splitlines()) == 1


def test_eval_tracking_reports_a_malformed_label_line(tmp_path: Path) -> None:
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "0001.txt").write_text("0 1 Car 0 0 0.1\n")
    for cls in ("Car", "Pedestrian", "Cyclist"):
        (tmp_path / "det" / f"pointrcnn_{cls}").mkdir(parents=True)
        (tmp_path / "det" / f"pointrcnn_{cls}" / "0001.txt").write_text("")
    result = CliRunner().invoke(
        app, ["eval", "tracking", "--detections", str(tmp_path / "det"), "--labels", str(tmp_path / "labels")]
    )
    assert result.exit_code == 2
    assert "0001.txt:1: expected 17 fields, got 6" in result.output


def test_eval_tracking_refuses_an_unknown_track_score_in_one_line(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        [
            "eval",
            "tracking",
            "--detections",
            str(tmp_path),
            "--labels",
            str(tmp_path),
            "--track-score",
            "median",
        ],
    )
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert (
        len(lines) == 1 and "track_score: expected one of ('last', 'evidence', 'mean', 'refined')" in lines[0]
    )


@pytest.mark.skipif(not DATA.is_dir(), reason=f"KITTI tracking data not found at {DATA}")
def test_eval_tracking_publishes_the_chosen_track_score(tmp_path: Path) -> None:
    scores = {}
    for mode in ("last", "refined"):
        res = tmp_path / mode
        args = [
            "--detections",
            str(DATA / "detections"),
            "--labels",
            str(DATA / "labels"),
            "--sequences",
            "0000",
        ]
        result = CliRunner().invoke(
            app, ["eval", "tracking", *args, "--track-score", mode, "--results", str(res)]
        )
        assert result.exit_code == 0, result.output
        scores[mode] = [float(line.split()[17]) for line in (res / "0000.txt").read_text().splitlines()]
    # Same tracks, other scores: the refined confidence (log-odds of the noisy-OR of the track's
    # detections) is at least the last detection's own, with the same coasting penalty on both.
    last, refined = np.array(scores["last"]), np.array(scores["refined"])
    assert len(last) == len(refined) and (refined >= last - 1e-6).all() and (refined > last + 0.1).any()
