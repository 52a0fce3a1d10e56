"""The default service in closed loop over seeds 0-4: the outcomes issue #2 guarantees.

These runs perceive through the radars (five 10-minute runs); the same outcomes with the raw LiDAR,
camera and radar perception, in clear weather and in snow, are in ``test_raw_perception_service.py``.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import pytest

from lastmile.core.perception_mode import PerceptionMode
from lastmile.evaluation.metrics import compute_metrics
from lastmile.recorder.run_log import RunLog
from lastmile.runner.closed_loop import run_scenario
from lastmile.sim.scenario import default_service
from tests.closed_loop.harness import RADAR

pytestmark = pytest.mark.closed_loop
SEEDS = (0, 1, 2, 3, 4)


@functools.cache
def _run(seed: int) -> tuple[RunLog, dict[str, Any]]:
    log = run_scenario(default_service(seed=seed), RADAR)
    return log, compute_metrics(log)


@pytest.mark.parametrize("seed", SEEDS)
def test_default_service_has_no_collision_and_no_takeover(seed: int) -> None:
    log, m = _run(seed)
    assert not log.events_of("stack_crash"), log.events_of("stack_crash")
    assert m["collisions_total"] == 0, log.events_of("collision")
    assert m["takeovers"] == 0, log.events_of("takeover")


@pytest.mark.parametrize("seed", SEEDS)
def test_default_service_breaks_no_rule(seed: int) -> None:
    log, m = _run(seed)
    assert m["rule_violations"] == 0, log.events_of("rule_violation")


@pytest.mark.parametrize("seed", SEEDS)
def test_every_stop_with_a_waiting_rider_is_served_at_the_curb(seed: int) -> None:
    log, m = _run(seed)
    served = log.events_of("stop_served")
    assert m["stops_missed"] == 0, log.events_of("stop_missed")
    assert {e.data["stop_id"] for e in served} >= {"S1", "S2", "S3", "S4"}
    for e in served:
        assert 0.0 < e.data["curb_gap_m"] <= 0.3, e
    assert m["passengers_served"] >= 4


@pytest.mark.parametrize("seed", SEEDS)
def test_the_shuttle_stops_at_the_all_way_stop(seed: int) -> None:
    log, _ = _run(seed)
    entries = log.events_of("intersection_entry")
    assert entries and all(e.data["order_ok"] for e in entries)


@pytest.mark.parametrize("seed", SEEDS)
def test_the_default_service_completes_its_loop_perceiving_through_radar(seed: int) -> None:
    log, m = _run(seed)
    assert log.events_of("loop_completed"), "the shuttle did not complete a loop in 10 minutes"
    assert m["perception_mode"] == "radar_tracking" and m["seed"] == seed


@pytest.mark.parametrize(("mode", "minutes"), [("radar_tracking", 2.0), ("lidar_camera_radar", 0.6)])
def test_same_seed_same_metrics(tmp_path: Path, mode: str, minutes: float) -> None:
    """Two runs of one seed write byte-identical metrics.json, in either perception mode."""
    from lastmile.runner.closed_loop import evaluate_run

    texts = []
    for name in ("a", "b"):
        log = run_scenario(
            default_service(seed=3, minutes=minutes), RADAR.with_perception(PerceptionMode(mode))
        )
        evaluate_run(log, tmp_path / name)
        texts.append((tmp_path / name / "metrics.json").read_bytes())
    assert texts[0] == texts[1]
