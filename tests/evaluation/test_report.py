"""The report: markdown with the run's identity, tables and non-empty PNG plots, with or without a map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from lastmile.core.polyline import Polyline
from lastmile.evaluation import metrics as m
from lastmile.evaluation import report as r
from lastmile.recorder.run_log import STATE_NAMES, RunLog

from .synthetic import make_log

TIMING = {
    "modules": {
        "planning": {"p50_ms": 2.5, "p95_ms": 4.0, "max_ms": 9.5, "calls": 300},
        "perception": {"p50_ms": 11.0, "p95_ms": 15.0, "max_ms": 30.0, "calls": 300},
    },
    "realtime_factor": 7.25,
}


def _log() -> RunLog:
    n = 3000
    t = np.arange(n) * 0.02
    speed = 2.0 + np.sin(t / 5.0)
    accel = np.gradient(speed, 0.02)
    state = (np.arange(n) // 500) % len(STATE_NAMES)
    events = [
        (
            10.0,
            "collision",
            {"agent_id": 4, "agent_class": "cyclist", "at_fault": False, "ego_speed_mps": 1.2},
        ),
        (20.0, "takeover", {"reason": "imminent_collision"}),
        (25.0, "rule_violation", {"rule": "stop_line", "detail": "ran stop line 3 | fast"}),
        (
            30.0,
            "stop_served",
            {"stop_id": "S1", "curb_gap_m": 0.23, "longitudinal_error_m": 0.4, "boarded": 1, "alighted": 0},
        ),
    ]
    log = make_log(speed, accel, state=state, events=events, agents=True)
    return RunLog(meta=log.meta, ego=log.ego, events=log.events, agents=log.agents, timing=TIMING)


def _assert_png(path: Path) -> None:
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    # Something was drawn: the image is not a single flat colour.
    assert float(image[..., :3].std()) > 0.01


def test_report_without_map_writes_markdown_and_plots(tmp_path: Path) -> None:
    log = _log()
    metrics = m.compute_metrics(log)
    path = r.write_report(log, metrics, tmp_path / "run")
    assert path == tmp_path / "run" / r.REPORT_FILE
    for png in (r.MAP_PNG, r.SPEED_PNG, r.COMFORT_PNG):
        _assert_png(path.parent / png)
        assert f"]({png})" in path.read_text()
    text = path.read_text()
    assert "| 1 | clear | **oracle** | synthetic | straight |" in text
    assert "ablation" in text
    assert f"| collisions_not_at_fault | {metrics['collisions_not_at_fault']} |" in text
    assert f"| distance_m | {metrics['distance_m']:.3f} |" in text
    assert (
        "| S1 | 30.0 | " in text and "| 0.23 | 0.40 | 1 | 0 | n/a |" in text
    )  # stops (no left_waiting: an older log)
    assert "ran stop line 3 \\| fast" in text  # a pipe in a detail must not split the table row
    assert "| planning | 300 | 2.500 | 4.000 | 9.500 |" in text
    assert "Real-time factor (simulated / wall-clock time): 7.250" in text


def test_report_draws_an_hd_map_under_the_path(tmp_path: Path) -> None:
    model = pytest.importorskip("lastmile.hdmap.model")
    xs = np.array([-10.0, 120.0])
    lanes = {
        1: model.LaneletInfo(
            id=1,
            centerline=Polyline(np.c_[xs, [0.0, 0.0]]),
            left=Polyline(np.c_[xs, [1.75, 1.75]]),
            right=Polyline(np.c_[xs, [-1.75, -1.75]]),
            speed_limit_mps=5.0,
        ),
        2: model.LaneletInfo(
            id=2,
            centerline=Polyline(np.array([[50.0, -3.0], [50.0, 3.0]])),
            left=Polyline(np.array([[48.0, -3.0], [48.0, 3.0]])),
            right=Polyline(np.array([[52.0, -3.0], [52.0, 3.0]])),
            speed_limit_mps=5.0,
            subtype="crosswalk",
        ),
    }
    stop = model.BusStop(
        id="S1",
        name="Library",
        lane_lanelet_id=1,
        bay_lanelet_id=1,
        curb=Polyline(np.array([[60.0, -4.75], [84.0, -4.75]])),
    )
    crosswalk = model.Crosswalk(
        id=2, polygon=np.array([[48.0, -3.0], [52.0, -3.0], [52.0, 3.0], [48.0, 3.0]]), width_m=4.0
    )
    hdmap = model.HDMap(name="test", lanelets=lanes, successor_ids={}, stops=(stop,), crosswalks=(crosswalk,))
    log = _log()
    plain = r.write_report(log, m.compute_metrics(log), tmp_path / "plain")
    with_map = r.write_report(log, m.compute_metrics(log), tmp_path / "map", hdmap=hdmap)
    _assert_png(with_map.parent / r.MAP_PNG)
    # The map layer changes the picture.
    assert not np.array_equal(imread(plain.parent / r.MAP_PNG), imread(with_map.parent / r.MAP_PNG))


def test_report_of_an_empty_log_still_renders(tmp_path: Path) -> None:
    log = make_log(np.zeros(0))
    path = r.write_report(log, m.compute_metrics(log), tmp_path)
    for png in (r.MAP_PNG, r.SPEED_PNG, r.COMFORT_PNG):
        assert (tmp_path / png).stat().st_size > 1000
    text = path.read_text()
    assert "No collisions, takeovers" in text and "No per-module timing recorded." in text


def test_malformed_timing_is_reported_naming_the_field(tmp_path: Path) -> None:
    log = make_log(np.ones(10))
    bad = RunLog(meta=log.meta, ego=log.ego, timing={"modules": {"planning": 3.0}})
    with pytest.raises(r.ReportError, match=r"timing.modules.planning: expected p50_ms"):
        r.write_report(bad, m.compute_metrics(bad), tmp_path)
