"""Localization and cross-track error over time: known offsets split along and across the true heading,
the summary figures in metrics.json, the report's plot, and a closed-loop run that logs them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.perception_mode import PerceptionMode
from lastmile.evaluation import metrics as m
from lastmile.evaluation import report as r
from lastmile.evaluation import report_pose
from lastmile.evaluation.pose_errors import POSE_METRICS, pose_errors, source_spans
from lastmile.recorder.run_log import STATE_NAMES, RunLog, RunMeta
from lastmile.recorder.run_log_writer import RunLogWriter
from lastmile.runner.closed_loop import run_scenario
from lastmile.runner.run_config import RunConfig
from lastmile.sim.scenario import Scenario


def _log(rows: list[tuple[float, ...]], pullover_from_s: float = math.inf) -> RunLog:
    """Ego trace of 4 s along x (in the pullover state from ``pullover_from_s``), plus the given
    localization rows."""
    w = RunLogWriter(
        RunMeta(
            seed=1,
            weather="clear",
            perception_mode="radar_tracking",
            scenario_name="synthetic",
            map_name="straight",
            tick_s=0.01,
            duration_s=4.0,
        )
    )
    for i in range(200):
        state = STATE_NAMES.index("pullover") if i * 0.02 >= pullover_from_s else 0
        w.add_ego_row(i * 0.02, i * 0.02, 0.0, 0.0, 1.0, 0.0, 0.0, state, i * 0.02)
    for row in rows:
        w.add_localization_row(*row)
    return w.finish()


def _row(
    t: float, dx: float, dy: float, yaw: float, std: float, code: int, d: float = 0.0
) -> tuple[float, ...]:
    """An estimate offset by (dx, dy) in the map from a true pose at (10, 5) heading ``yaw``."""
    return (t, 10.0 + dx, 5.0 + dy, yaw, std, 0.01, code, 10.0, 5.0, yaw, d, d / 2.0)


def test_an_offset_splits_into_along_track_and_lateral_in_the_true_heading() -> None:
    # Heading north: an estimate 1 m east is 1 m to the right (lateral -1), none along; 2 m north is
    # 2 m ahead.
    log = _log([_row(0.1, 1.0, 0.0, math.pi / 2, 0.5, 0), _row(0.2, 0.0, 2.0, math.pi / 2, 0.5, 0)])
    e = pose_errors(log)
    assert e.lateral_m == pytest.approx([-1.0, 0.0], abs=1e-12)
    assert e.along_m == pytest.approx([0.0, 2.0], abs=1e-12)
    assert e.total_m == pytest.approx([1.0, 2.0])
    assert e.band_m == pytest.approx([0.98, 0.98])


def test_invalid_estimates_count_in_no_error_figure_and_shade_as_invalid() -> None:
    rows = [
        _row(0.1, 50.0, 0.0, 0.0, 5.0, -1),  # flagged invalid: its 50 m must not reach the figures
        _row(0.2, 0.1, 0.0, 0.0, 0.1, 0),
        _row(0.3, 0.0, 0.3, 0.0, 0.1, 2),
        _row(0.4, 0.0, -0.2, 0.0, 0.1, 2),
    ]
    e = pose_errors(_log(rows))
    assert np.isnan(e.total_m[0])
    assert source_spans(e) == [(0.1, 0.2, "invalid"), (0.2, 0.3, "gnss"), (0.3, 0.4, "dead_reckoning")]
    metrics = m.compute_metrics(_log(rows))
    assert metrics["localization_error_max_m"] == pytest.approx(0.3)
    assert metrics["localization_lateral_error_max_m"] == pytest.approx(0.3)
    assert metrics["localization_along_error_max_m"] == pytest.approx(0.1)
    # 1.96 * 0.1 = 0.196: the 0.3 m and 0.2 m lateral errors leave the band, the 0 m one does not.
    assert metrics["localization_lateral_outside_band_share"] == pytest.approx(2 / 3)


def test_cross_track_figures_are_of_the_absolute_offsets() -> None:
    rows = [_row(0.1 * (k + 1), 0.0, 0.0, 0.0, 0.1, 0, d) for k, d in enumerate(np.linspace(-1.0, 0.5, 21))]
    metrics = m.compute_metrics(_log(rows))
    assert metrics["cross_track_error_route_max_m"] == pytest.approx(1.0)
    assert metrics["cross_track_error_path_max_m"] == pytest.approx(0.5)
    expected_p95 = float(np.percentile(np.abs(np.linspace(-1.0, 0.5, 21)), 95.0))
    assert metrics["cross_track_error_route_p95_m"] == pytest.approx(expected_p95)


def test_a_pull_over_leaves_the_route_centre_line_on_purpose_and_is_not_a_cross_track_error(
    tmp_path: Path,
) -> None:
    # In lane (0.1 m off) until 2 s, then pulled over 3.5 m to the right of the centre line.
    rows = [_row(0.1 * k, 0.0, 0.0, 0.0, 0.1, 0, 0.1 if k < 20 else -3.5) for k in range(1, 31)]
    log = _log(rows, pullover_from_s=2.0)
    metrics = m.compute_metrics(log)
    assert metrics["cross_track_error_route_max_m"] == pytest.approx(0.1)
    assert metrics["cross_track_error_path_max_m"] == pytest.approx(1.75)  # the plan followed the bay
    r.write_report(log, metrics, tmp_path)
    text = (tmp_path / r.REPORT_FILE).read_text()
    assert "| cross-track from the route centre line, in lane | 0.100 | 0.100 | 0.100 |" in text
    assert "| cross-track from the route centre line, all | 0.100 | 3.500 | 3.500 |" in text


def test_a_log_without_the_table_gives_none_for_the_new_keys_only() -> None:
    metrics = m.compute_metrics(_log([]))
    assert all(metrics[name] is None for name in POSE_METRICS)
    assert metrics["distance_m"] == pytest.approx(3.98)


def test_the_report_plots_the_errors_and_tabulates_them(tmp_path: Path) -> None:
    rows = [_row(0.1 * (k + 1), 0.01 * k, 0.0, 0.0, 0.1, 0 if k < 10 else 1, 0.02) for k in range(20)]
    log = _log(rows)
    r.write_report(log, m.compute_metrics(log), tmp_path)
    assert (tmp_path / report_pose.POSE_PNG).stat().st_size > 5_000
    text = (tmp_path / r.REPORT_FILE).read_text()
    assert f"]({report_pose.POSE_PNG})" in text
    assert "| localization, along-track | 0.095 | 0.180 | 0.190 |" in text
    assert "| landmarks | 10 |" in text and "| gnss | 10 |" in text


def test_a_closed_loop_run_logs_the_stacks_estimate_beside_the_truth() -> None:
    radar = RunConfig().with_perception(PerceptionMode.RADAR_TRACKING)
    log = run_scenario(Scenario(name="short", minutes=0.05), radar)
    loc = log.localization
    # One row per planning cycle (10 Hz) over 3 s.
    assert 29 <= len(loc) <= 31
    assert np.all(np.diff(loc.column("t_s")) == pytest.approx(0.1))
    e = pose_errors(log)
    assert e.valid.sum() >= len(loc) - 2
    # GNSS-held estimates on the campus: centimetres, inside the stack's own band most of the time.
    assert np.nanmax(e.total_m) < 0.5
    assert np.isfinite(e.route_d_m).all() and np.nanmax(np.abs(e.route_d_m)) < 0.5
    assert np.isfinite(e.path_d_m[5:]).all()
    # The true pose in the table is the vehicle's at the estimate's instant: it lies on the ego trace.
    ego_x = np.interp(loc.column("t_s"), log.column("t_s") + log.meta.tick_s, log.column("x_m"))
    assert loc.column("true_x_m")[1:] == pytest.approx(ego_x[1:], abs=1e-3)
