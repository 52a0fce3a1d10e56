"""The report explains a run: road users drawn, encounters merged and viewed, real causes, failed checks
with reasons, stops one by one, and one self-contained HTML file."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.polyline import Polyline
from lastmile.evaluation import metrics as m
from lastmile.evaluation import report as r
from lastmile.evaluation import report_views
from lastmile.runner.closed_loop import run_scenario
from lastmile.runner.run_config import RunConfig
from lastmile.sim.scenario import RingCar, Scenario

from .synthetic import make_log

N = 3000  # 60 s at 50 Hz
RADAR = PerceptionMode.RADAR_TRACKING


def _ttc_events(agent: int, t0: float, count: int) -> list[tuple[float, str, dict[str, object]]]:
    # The referee logs each new minimum: a falling series, one sample per 0.1 s.
    return [
        (t0 + 0.1 * k, "min_ttc", {"ttc_s": round(2.9 - 0.1 * k, 3), "agent_id": agent}) for k in range(count)
    ]


def _log(events: list[tuple[float, str, dict[str, object]]], accel: np.ndarray | None = None):  # type: ignore[no-untyped-def]
    road_users = [
        (0.0, "road_user", {"agent_id": 5, "agent_class": "pedestrian"}),
        (0.0, "road_user", {"agent_id": 7, "agent_class": "car"}),
    ]
    return make_log(np.full(N, 2.0), accel, events=[*road_users, *events], agents=True)


def test_consecutive_min_ttc_rows_of_one_encounter_are_one_row(tmp_path: Path) -> None:
    events = [*_ttc_events(5, 20.0, 18), *_ttc_events(7, 21.0, 3), *_ttc_events(5, 40.0, 2)]
    log = _log(sorted(events, key=lambda e: e[0]))
    found = report_views.encounters(log)
    assert [(e.agent_id, len(e.samples)) for e in found] == [(5, 18), (7, 3), (5, 2)]
    first = found[0]
    assert first.agent_class == "pedestrian" and first.min_ttc_s == pytest.approx(1.2)
    assert first.t_min_s == pytest.approx(21.7)
    text = r.write_report(log, m.compute_metrics(log), tmp_path).read_text()
    assert text.count("| min_ttc |") == 0
    assert "| 21.70 | encounter | pedestrian 5: min TTC 1.20 s (18 samples, 20.0-21.7 s) |" in text
    assert "![encounter views](encounters.png)" in text
    assert (tmp_path / report_views.ENCOUNTERS_PNG).stat().st_size > 10_000


def test_an_operator_estop_is_named_as_the_cause_of_the_takeover_and_the_emergency_stop(
    tmp_path: Path,
) -> None:
    events = [
        (30.0, "operator_estop", {"state": "cruising"}),
        (30.01, "takeover", {"reason": "stack_request"}),
        (30.01, "emergency_stop", {"reason": "emergency stop"}),
        (38.0, "operator_release", {"state": "emergency_stop"}),
    ]
    log = _log(events)
    text = r.write_report(log, m.compute_metrics(log), tmp_path).read_text()
    cause = "cause: operator e-stop pressed at 30.00 s in state cruising"
    assert f"| 30.01 | takeover | reason=stack_request; {cause} |" in text
    assert f"| 30.01 | emergency_stop | reason=emergency stop; {cause} |" in text
    assert "- takeover at 30.0 s: operator e-stop pressed at 30.00 s in state cruising" in text


def test_a_failed_comfort_check_says_which_limit_when_and_by_how_much(tmp_path: Path) -> None:
    accel = np.zeros(N)
    accel[1000:1050] = 1.5  # a 1 s step of 1.5 m/s^2: the jerk of its edges breaks 2.5 m/s^3
    log = _log([], accel)
    metrics = m.compute_metrics(log)
    assert metrics["comfort_compliant"] == 0
    text = r.write_report(log, metrics, tmp_path).read_text()
    found = re.search(
        r"- comfort: max_abs_jerk_mps3: ([+-]\d+\.\d\d) m/s\^3 beyond [+-]2\.50 "
        r"at t (\d+\.\d) s \(\w+; (\d+) samples",
        text,
    )
    assert found is not None, text
    assert abs(float(found.group(1))) > 2.5 and float(found.group(2)) in (20.0, 21.0)


def test_a_clean_run_lists_no_failed_check(tmp_path: Path) -> None:
    log = _log([])
    text = r.write_report(log, m.compute_metrics(log), tmp_path).read_text()
    assert "## Checks failed\n\nNone." in text


def _straight_map():  # type: ignore[no-untyped-def]
    model = pytest.importorskip("lastmile.hdmap.model")
    xs = np.array([-10.0, 150.0])
    lane = model.LaneletInfo(
        id=1,
        centerline=Polyline(np.c_[xs, [0.0, 0.0]]),
        left=Polyline(np.c_[xs, [1.75, 1.75]]),
        right=Polyline(np.c_[xs, [-1.75, -1.75]]),
        speed_limit_mps=5.0,
    )
    stop = model.BusStop(
        id="S1",
        name="Library",
        lane_lanelet_id=1,
        bay_lanelet_id=1,
        curb=Polyline(np.array([[60.0, -4.75], [84.0, -4.75]])),
    )
    return model.HDMap(name="test", lanelets={1: lane}, successor_ids={}, stops=(stop,))


def test_stops_get_insets_and_the_html_report_is_one_self_contained_file(tmp_path: Path) -> None:
    log = _log(_ttc_events(5, 20.0, 5))
    r.write_report(log, m.compute_metrics(log), tmp_path, hdmap=_straight_map())
    assert (tmp_path / report_views.PLACES_PNG).stat().st_size > 5_000
    html = (tmp_path / r.HTML_FILE).read_text()
    assert html.startswith("<!DOCTYPE html>")
    images = re.findall(r'<img alt="[^"]*" src="([^"]*)"', html)
    assert len(images) >= 5 and all(src.startswith("data:image/png;base64,") for src in images)
    assert "<table>" in html and "<h2>Stops and intersections</h2>" in html


def test_a_closed_loop_run_logs_the_other_road_users_with_their_class() -> None:
    scenario = Scenario(name="one_car", minutes=0.05, ring_cars=(RingCar(direction="cw", start_s_m=100.0),))
    log = run_scenario(scenario, RunConfig().with_perception(RADAR))
    assert len(log.agents) > 0
    classes = report_views.road_user_classes(log)
    assert "car" in classes.values()
    ids = set(np.unique(log.agents.agent_id).tolist())
    assert ids <= set(classes)
    # 2 Hz: 3 s of run give 6 samples of each road user.
    per_user = np.bincount(log.agents.agent_id)
    assert per_user[per_user > 0].max() == 6


def test_warm_up_is_apart_from_the_real_time_factor_and_reported(tmp_path: Path) -> None:
    from lastmile.runner.closed_loop import evaluate_run

    log = run_scenario(Scenario(name="short", minutes=0.05), RunConfig().with_perception(RADAR))
    timing = log.timing
    assert timing["warmup_s"] > 0.0
    assert timing["realtime_factor"] > timing["realtime_factor_with_warmup"]
    assert all(row["warmup_ms"] is not None for row in timing["modules"].values())
    evaluate_run(log, tmp_path)
    assert "Warm-up (each module's first call" in (tmp_path / "report.md").read_text()


def test_latency_histograms_show_each_module_against_its_budget(tmp_path: Path) -> None:
    log = run_scenario(Scenario(name="short", minutes=0.05), RunConfig().with_perception(RADAR))
    planning = log.timing["modules"]["planning"]
    assert planning["budget_ms"] == 100.0 and planning["over_budget"] is not None
    from lastmile.runner.closed_loop import evaluate_run

    evaluate_run(log, tmp_path)
    text = (tmp_path / "report.md").read_text()
    assert "| budget [ms] | over budget |" in text
    assert f"![per-module latency histograms against the cycle budget]({r.LATENCY_PNG})" in text
    assert (tmp_path / r.LATENCY_PNG).stat().st_size > 10_000


def test_each_stop_visit_says_how_many_riders_were_left_waiting_and_whether_the_shuttle_was_full(
    tmp_path: Path,
) -> None:
    served = {"curb_gap_m": 0.2, "longitudinal_error_m": 0.1, "boarded": 1, "alighted": 0}
    log = _log(
        [
            (10.0, "stop_served", {"stop_id": "S1", **served, "left_waiting": 2, "seats_free": 0}),
            (30.0, "stop_served", {"stop_id": "S2", **served, "left_waiting": 1, "seats_free": 3}),
            (50.0, "stop_served", {"stop_id": "S3", **served, "left_waiting": 0, "seats_free": 3}),
        ]
    )
    r.write_report(log, m.compute_metrics(log), tmp_path)
    rows = [ln for ln in (tmp_path / r.REPORT_FILE).read_text().splitlines() if ln.startswith("| S")]
    assert [row.rsplit("|", 2)[1].strip() for row in rows] == ["2 (full)", "1", "0"]


def test_a_takeover_the_vehicle_safety_asked_for_says_why(tmp_path: Path) -> None:
    reason = "localization: protection level 1.96 sigma = 0.75 m > lane margin 0.75 m"
    events = [
        (20.0, "safety", {"level": "SPEED_LIMIT", "mrm": "NONE", "reason": "sensor:gnss: no fix"}),
        (34.7, "safety", {"level": "MINIMAL_RISK_MANOEUVRE", "mrm": "STOP_IN_LANE", "reason": reason}),
        (34.7, "takeover", {"reason": "stack_request"}),
    ]
    log = _log(events)
    text = r.write_report(log, m.compute_metrics(log), tmp_path).read_text()
    cause = f"vehicle safety's minimal risk manoeuvre (stop in lane) at 34.70 s: {reason}"
    assert f"- takeover at 34.7 s: {cause}" in text
    assert f"| 34.70 | takeover | reason=stack_request; cause: {cause} |" in text
