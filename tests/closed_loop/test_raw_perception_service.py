"""The default service with the default perception (raw LiDAR, camera and radar), in clear weather and
in snow: the outcomes issue #2 guarantees, now with the stack seeing only raw sensor data.

The two 10-minute runs go to two worker processes at once (the suite's slowest item otherwise).
"""

from __future__ import annotations

import functools
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import pytest

from lastmile.evaluation.metrics import compute_metrics
from lastmile.recorder.run_log import RunLog
from lastmile.runner.closed_loop import DEFAULT_CONFIG, run_scenario
from lastmile.runner.sweep import pin_blas_threads
from lastmile.sim.scenario import default_service

pytestmark = pytest.mark.closed_loop
WEATHERS = ("clear", "snow")


def _one(weather: str) -> RunLog:
    return run_scenario(default_service(seed=0, weather=weather))


@functools.cache
def _runs() -> dict[str, tuple[RunLog, dict[str, Any]]]:
    with ProcessPoolExecutor(max_workers=2, initializer=pin_blas_threads) as pool:
        logs = dict(zip(WEATHERS, pool.map(_one, WEATHERS), strict=True))
    return {w: (log, compute_metrics(log)) for w, log in logs.items()}


@pytest.mark.parametrize("weather", WEATHERS)
def test_raw_perception_is_the_default_and_the_report_says_so(weather: str) -> None:
    log, m = _runs()[weather]
    assert DEFAULT_CONFIG.stack.perception == "lidar_camera_radar"
    assert m["perception_mode"] == "lidar_camera_radar" and log.meta.weather == weather
    raw = log.timing["raw_perception"]
    # Every 10 Hz rig frame of the run was perceived, with all three LiDARs' sweeps in it.
    assert raw["rig_frames"] >= 5990 and raw["incomplete_frames"] == 0 and raw["skipped_no_pose"] <= 1


@pytest.mark.parametrize("weather", WEATHERS)
def test_no_collision_takeover_or_rule_violation(weather: str) -> None:
    log, m = _runs()[weather]
    assert not log.events_of("stack_crash"), log.events_of("stack_crash")
    assert m["collisions_total"] == 0, log.events_of("collision")
    assert m["takeovers"] == 0, log.events_of("takeover")
    assert m["rule_violations"] == 0, log.events_of("rule_violation")


@pytest.mark.parametrize("weather", WEATHERS)
def test_every_stop_is_served_at_the_curb_and_the_all_way_stop_kept(weather: str) -> None:
    log, m = _runs()[weather]
    served = log.events_of("stop_served")
    assert m["stops_missed"] == 0, log.events_of("stop_missed")
    assert {e.data["stop_id"] for e in served} >= {"S1", "S2", "S3", "S4"}
    for e in served:
        assert 0.0 < e.data["curb_gap_m"] <= 0.3, e
    entries = log.events_of("intersection_entry")
    assert entries and all(e.data["order_ok"] for e in entries)


@pytest.mark.parametrize("weather", WEATHERS)
def test_the_loop_is_completed(weather: str) -> None:
    log, _ = _runs()[weather]
    assert log.events_of("loop_completed"), "the shuttle did not complete a loop in 10 minutes"
