"""Metrics on synthetic logs whose answers are known by hand."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lastmile.core.errors import ConfigError
from lastmile.evaluation import metrics as m
from lastmile.evaluation import run_signals as rs
from lastmile.recorder.run_log import RULES, STATE_NAMES

from .synthetic import TICK_S, make_log

REQUIRED = [
    "distance_m",
    "duration_s",
    "collisions_total",
    "collisions_at_fault",
    "takeovers",
    "stops_served",
    "stops_missed",
    "passengers_served",
    "max_speed_mps",
    "mean_speed_mps",
    "min_accel_mps2",
    "max_accel_mps2",
    "min_jerk_mps3",
    "max_jerk_mps3",
    "rule_violations",
    "perception_mode",
    "seed",
    "weather",
    "share_time_at_or_above_9kph",
    "hard_braking_events",
    "km_per_hard_braking",
    "km_per_takeover",
    "passengers_boarded",
    "passengers_alighted",
    "mean_wait_s",
    "max_wait_s",
    "mean_ride_s",
    "pullover_curb_gap_mean_m",
    "pullover_curb_gap_max_m",
    "loops_completed",
    "emergency_stops",
    "min_ttc_s",
    "closed_loop_score",
]


def _ramp(accel_mps2: float = 0.5, duration_s: float = 20.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(round(duration_s / TICK_S) + 1) * TICK_S
    return t, accel_mps2 * t, 0.5 * accel_mps2 * t**2


def test_every_required_key_is_present() -> None:
    out = m.compute_metrics(make_log(np.ones(10)))
    missing = [k for k in REQUIRED if k not in out]
    missing += [f"rule_violations_{r}" for r in RULES if f"rule_violations_{r}" not in out]
    assert missing == []


def test_constant_acceleration_ramp_has_known_speed_accel_and_zero_jerk() -> None:
    t, v, x = _ramp()
    out = m.compute_metrics(make_log(v, np.full(len(t), 0.5), x_m=x))
    assert out["duration_s"] == 20.0
    assert out["distance_m"] == pytest.approx(100.0, abs=1e-6)
    assert out["mean_speed_mps"] == pytest.approx(5.0, abs=1e-6)
    assert out["max_speed_mps"] == pytest.approx(10.0)
    assert out["min_accel_mps2"] == out["max_accel_mps2"] == 0.5
    assert out["min_jerk_mps3"] == 0.0 and out["max_jerk_mps3"] == 0.0
    # v >= 2.5 m/s from t = 5 s to the end: 15 of 20 s.
    assert out["share_time_at_or_above_9kph"] == pytest.approx(0.75, abs=1e-6)
    assert out["hard_braking_events"] == 0 and out["km_per_hard_braking"] is None


def test_linear_acceleration_gives_its_slope_as_jerk() -> None:
    t, _, _ = _ramp()
    accel = 0.3 * t - 2.0
    out = m.compute_metrics(make_log(np.full(len(t), 3.0), accel))
    assert out["min_jerk_mps3"] == pytest.approx(0.3, abs=1e-6)
    assert out["max_jerk_mps3"] == pytest.approx(0.3, abs=1e-6)


def test_jerk_uses_window_means_so_a_single_tick_spike_is_damped() -> None:
    n = 500
    accel = np.zeros(n)
    accel[250] = 1.0  # one 20 ms spike: 50 m/s^3 at the raw rate, 2 m/s^3 after 0.1 s averaging
    out = m.compute_metrics(make_log(np.full(n, 3.0), accel))
    assert out["max_jerk_mps3"] == pytest.approx(2.0, abs=1e-6)
    assert out["min_jerk_mps3"] == pytest.approx(-2.0, abs=1e-6)


def test_one_km_with_two_takeovers_is_half_a_km_per_takeover() -> None:
    n = 10_001  # 200 s at 5 m/s: 1000 m
    takeovers = [(50.0, "takeover", {"reason": "stall"}), (120.0, "takeover", {"reason": "stack_request"})]
    out = m.compute_metrics(make_log(np.full(n, 5.0), events=takeovers))
    assert out["distance_m"] == pytest.approx(1000.0)
    assert out["takeovers"] == 2
    assert out["km_per_takeover"] == pytest.approx(0.5)
    assert out["takeovers_stall"] == 1 and out["takeovers_stack_request"] == 1
    assert out["takeovers_imminent_collision"] == 0


def test_no_takeover_gives_null_km_per_takeover() -> None:
    out = m.compute_metrics(make_log(np.full(100, 5.0)))
    assert out["takeovers"] == 0 and out["km_per_takeover"] is None


def _braking_profile(release_hover: bool) -> np.ndarray:
    windows = [0.0] * 20 + [-1.5] * 10 + [0.0] * 20 + [-1.2] * 10 + [0.0] * 20
    # Twenty windows hovering around the threshold: one episode with hysteresis.
    windows += [-1.0, -0.95] * 10 if release_hover else []
    windows += [0.0] * 10
    return np.repeat(windows, 5)


def test_hard_braking_counts_entries_into_episodes_with_hysteresis() -> None:
    accel = _braking_profile(release_hover=True)
    log = make_log(np.full(len(accel), 4.0), accel)
    assert m.compute_metrics(log)["hard_braking_events"] == 3
    no_hysteresis = rs.ComfortLimits(hard_braking_release_mps2=0.0)
    assert m.compute_metrics(log, no_hysteresis)["hard_braking_events"] == 12
    out = m.compute_metrics(log)
    assert out["km_per_hard_braking"] == pytest.approx(out["distance_m"] / 1000.0 / 3, abs=1e-6)


def test_collisions_are_split_by_fault_and_any_at_fault_zeroes_the_score() -> None:
    hit = {"agent_class": "pedestrian", "ego_speed_mps": 2.0}
    events = [
        (1.0, "collision", {"agent_id": 1, "at_fault": True, **hit}),
        (2.0, "collision", {"agent_id": 2, "at_fault": False, **hit}),
        (3.0, "collision", {"agent_id": 3, "at_fault": True, **hit}),
    ]
    out = m.compute_metrics(make_log(np.full(500, 2.0), events=events))
    assert (out["collisions_total"], out["collisions_at_fault"], out["collisions_not_at_fault"]) == (3, 2, 1)
    assert out["closed_loop_score"] == 0.0
    not_at_fault = m.compute_metrics(make_log(np.full(500, 2.0), events=[events[1]]))
    assert not_at_fault["closed_loop_score"] == 1.0


def test_identical_logs_give_identical_metrics() -> None:
    accel = _braking_profile(release_hover=True)
    events = [(1.0, "min_ttc", {"ttc_s": 1.2, "agent_id": 4})]
    a = m.compute_metrics(make_log(np.full(len(accel), 4.0), accel, events=events))
    b = m.compute_metrics(make_log(np.full(len(accel), 4.0), accel, events=events))
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    c = m.compute_metrics(make_log(np.full(len(accel), 4.0), accel, events=events, seed=2))
    assert c["seed"] == 2 and {k for k in a if a[k] != c[k]} == {"seed"}


def test_metrics_json_round_trips_with_sorted_keys_and_nulls(tmp_path: Path) -> None:
    out = m.compute_metrics(make_log(np.full(100, 1.0)))
    path = m.write_metrics(out, tmp_path)
    text = path.read_text()
    assert json.loads(text) == out == m.load_metrics(tmp_path)
    keys = list(json.loads(text))
    assert keys == sorted(keys)
    assert '"km_per_takeover": null' in text


def test_write_metrics_rejects_non_json_values(tmp_path: Path) -> None:
    with pytest.raises(m.MetricsError, match="JSON-able"):
        m.write_metrics({"x": math.nan}, tmp_path)
    with pytest.raises(m.MetricsError, match="no such file"):
        m.load_metrics(tmp_path / "absent")


def test_timing_goes_to_its_own_file(tmp_path: Path) -> None:
    timing = {"realtime_factor": 12.5, "modules": {"planning": {"p50_ms": 1.0, "p95_ms": 2.0}}}
    path = m.write_timing(timing, tmp_path)
    assert path.name == "timing.json" and json.loads(path.read_text()) == timing
    log = make_log(np.ones(10))
    assert not any("realtime" in k or "_ms" in k for k in m.compute_metrics(log))


def test_service_events_give_counts_waits_rides_and_curb_gaps() -> None:
    events = [
        (
            10.0,
            "stop_served",
            {"stop_id": "A", "curb_gap_m": 0.2, "longitudinal_error_m": 0.5, "boarded": 2, "alighted": 0},
        ),
        (10.5, "passenger_boarded", {"passenger_id": 1, "stop_id": "A", "wait_s": 30.0}),
        (11.0, "passenger_boarded", {"passenger_id": 2, "stop_id": "A", "wait_s": 90.0}),
        (
            20.0,
            "stop_served",
            {"stop_id": "B", "curb_gap_m": 0.4, "longitudinal_error_m": 0.0, "boarded": 0, "alighted": 1},
        ),
        (20.5, "passenger_alighted", {"passenger_id": 1, "stop_id": "B", "ride_s": 10.0}),
        (25.0, "stop_missed", {"stop_id": "C", "waiting": 3}),
        (26.0, "loop_completed", {"loop": 1}),
        (27.0, "loop_completed", {"loop": 2}),
        (28.0, "emergency_stop", {"reason": "pedestrian"}),
    ]
    out = m.compute_metrics(make_log(np.full(1500, 3.0), events=events))
    assert (out["stops_served"], out["stops_missed"]) == (2, 1)
    assert (out["passengers_served"], out["passengers_boarded"], out["passengers_alighted"]) == (2, 2, 1)
    assert (out["mean_wait_s"], out["max_wait_s"], out["mean_ride_s"]) == (60.0, 90.0, 10.0)
    assert out["pullover_curb_gap_mean_m"] == pytest.approx(0.3)
    assert out["pullover_curb_gap_max_m"] == 0.4
    assert out["pullover_longitudinal_error_max_m"] == 0.5
    assert out["loops_completed"] == 2 and out["emergency_stops"] == 1


def test_no_passengers_give_null_waits() -> None:
    out = m.compute_metrics(make_log(np.full(10, 3.0)))
    assert out["mean_wait_s"] is None and out["pullover_curb_gap_mean_m"] is None and out["min_ttc_s"] is None


def test_rule_violations_are_counted_per_rule() -> None:
    events = [
        (1.0, "rule_violation", {"rule": r, "detail": ""}) for r in ("stop_line", "stop_line", "red_light")
    ]
    events.append((2.0, "rule_violation", {"rule": "crosswalk_yield", "detail": "cw 3"}))
    out = m.compute_metrics(make_log(np.full(200, 3.0), events=events))
    assert out["rule_violations"] == 4
    assert out["rule_violations_stop_line"] == 2 and out["rule_violations_crosswalk_yield"] == 1
    assert out["rule_violations_other"] == 1 and out["rule_violations_speed_limit"] == 0


def _speeding(config: dict[str, object], flagged: bool) -> dict[str, object]:
    # 20 s; 7 m/s from 5 s to 10 s, 5 m/s elsewhere; the limit is 5.56 m/s.
    speed = np.full(1001, 5.0)
    speed[250:500] = 7.0
    events = [(6.5, "rule_violation", {"rule": "speed_limit", "detail": "7.00 m/s"})] if flagged else []
    return m.compute_metrics(make_log(speed, events=events, config=config))


def test_time_over_the_limit_counts_only_flagged_episodes() -> None:
    limit = {"speed_limit_mps": 20 / 3.6}
    out = _speeding(limit, flagged=True)
    assert out["time_over_speed_limit_s"] == pytest.approx(5.0)
    assert out["speed_limit_compliance"] == pytest.approx(0.75)
    assert out["closed_loop_score"] == pytest.approx((5 + 4 * 0.75 + 2 + 5) / 16)
    assert _speeding(limit, flagged=False)["speed_limit_compliance"] == 1.0


def test_without_a_configured_limit_the_flagged_episode_is_estimated_from_the_trace() -> None:
    assert _speeding({}, flagged=True)["time_over_speed_limit_s"] == pytest.approx(5.0)


@pytest.mark.parametrize(
    ("events", "config", "expected"),
    [
        ([], {"expected_distance_m": 120.0}, (5 + 4 + 2 + 5 * 0.5) / 16),
        ([(1.0, "min_ttc", {"ttc_s": 0.5, "agent_id": 1})], {}, (4 + 2 + 5) / 16),
        ([(1.0, "min_ttc", {"ttc_s": 0.95, "agent_id": 1})], {}, 1.0),
        ([(1.0, "rule_violation", {"rule": "drivable_area", "detail": ""})], {}, 0.0),
        ([], {"expected_distance_m": 600.0}, 0.5 * (5 + 4 + 2 + 5 * 0.1) / 16),
    ],
)
def test_closed_loop_score_follows_its_formula(
    events: list[tuple[float, str, dict[str, object]]], config: dict[str, object], expected: float
) -> None:
    out = m.compute_metrics(make_log(np.full(1001, 3.0), events=events, config=config))  # 60 m in 20 s
    assert out["closed_loop_score"] == pytest.approx(expected, abs=1e-6)


def test_comfort_exceedance_fails_comfort_unless_inside_an_emergency() -> None:
    speed = np.full(1000, 4.0)
    accel = np.zeros(1000)
    accel[500:] = -3.5  # a step to -3.5 m/s^2: beyond the 3.0 braking limit, 35 m/s^3 of jerk
    out = m.compute_metrics(make_log(speed, accel))
    assert out["comfort_compliant"] == 0
    assert out["closed_loop_score"] == pytest.approx(14 / 16)
    state = np.zeros(1000, dtype=int)
    state[500:] = STATE_NAMES.index("emergency_stop")
    assert m.compute_metrics(make_log(speed, accel, state=state))["comfort_compliant"] == 1
    event = [(9.99, "emergency_stop", {"reason": "pedestrian"})]
    assert m.compute_metrics(make_log(speed[:650], accel[:650], events=event))["comfort_compliant"] == 1


def test_time_shares_of_states_sum_to_one() -> None:
    state = np.repeat(np.arange(len(STATE_NAMES)), 100)
    out = m.compute_metrics(make_log(np.full(len(state), 2.0), state=state))
    shares = [out[f"time_share_{s}"] for s in STATE_NAMES]
    assert sum(shares) == pytest.approx(1.0)  # type: ignore[arg-type]
    assert out["time_share_normal_driving"] == pytest.approx(100 / 599)


def test_empty_log_gives_nulls_not_errors() -> None:
    out = m.compute_metrics(make_log(np.zeros(0)))
    assert out["duration_s"] == 0.0 and out["max_speed_mps"] is None and out["closed_loop_score"] is None


def test_bad_config_values_are_rejected() -> None:
    with pytest.raises(ConfigError, match=r"expected_distance_m: expected a finite number, got 'far'"):
        m.compute_metrics(make_log(np.ones(10), config={"expected_distance_m": "far"}))
    with pytest.raises(ConfigError, match="max_abs_jerk_mps3: expected a finite number > 0, got -1"):
        rs.ComfortLimits(max_abs_jerk_mps3=-1)


def test_registry_refuses_a_duplicate_name() -> None:
    assert len(set(m.metric_names())) == len(m.metric_names())
    with pytest.raises(ConfigError, match="twice"):
        m.register_metric("distance_m")(lambda sig: m.MetricResult(0.0))
    assert m.metric("distance_m")(rs.RunSignals(make_log(np.ones(3)), rs.ComfortLimits())).valid


@given(st.lists(st.booleans(), max_size=60))
def test_true_runs_are_the_maximal_runs_of_the_mask(bits: list[bool]) -> None:
    mask = np.array(bits, dtype=bool)
    runs = rs.true_runs(mask)
    rebuilt = np.zeros(len(mask), dtype=bool)
    for start, stop in runs:
        rebuilt[start:stop] = True
    assert np.array_equal(rebuilt, mask)
    # Maximal: consecutive runs are separated by at least one False.
    assert all(prev[1] < nxt[0] for prev, nxt in itertools.pairwise(runs))


def test_comfort_failure_says_which_limit_by_how_much_and_when() -> None:
    speed = np.full(1000, 4.0)
    accel = np.zeros(1000)
    accel[500:] = -3.5  # from t = 10 s: beyond the 3.0 m/s^2 braking limit and a 35 m/s^3 jerk step
    out = m.compute_metrics(make_log(speed, accel))
    why = out["comfort_violation"]
    assert isinstance(why, str)
    assert "max_decel_mps2: -3.50 m/s^2 beyond -3.00 at t 10.0 s (normal_driving; 100 samples" in why
    assert "max_abs_jerk_mps3: -35.00 m/s^3 beyond -2.50 at t 10.0 s (normal_driving; 1 sample " in why
    assert "max_accel_mps2" not in why
    assert out["comfort_min_accel_mps2"] == pytest.approx(-3.5)
    assert out["comfort_min_jerk_mps3"] == pytest.approx(-35.0)


def test_snow_lion_envelope_is_tighter_than_the_shuttle_limits() -> None:
    speed = np.full(1000, 4.0)
    accel = np.full(1000, 1.5)  # inside the shuttle's 2.0 m/s^2, beyond Snow Lion's 1.12
    out = m.compute_metrics(make_log(speed, accel))
    assert out["comfort_compliant"] == 1 and out["comfort_violation"] is None
    assert out["snow_lion_comfort_compliant"] == 0
    assert str(out["snow_lion_comfort_violation"]).startswith("max_accel_mps2: +1.50 m/s^2 beyond +1.12")
