"""Run log: writer checks, file round trip, and errors that name the bad file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import LastmileError
from lastmile.core.vehicle_messages import BehaviourState
from lastmile.recorder.run_log import (
    AGENTS_FILE,
    EGO_COLUMNS,
    EGO_FILE,
    LOCALIZATION_FILE,
    RUN_LOG_FILE,
    STATE_NAMES,
    RunLog,
    RunLogError,
    RunMeta,
)
from lastmile.recorder.run_log_writer import RunLogWriter


def _meta(**kw: object) -> RunMeta:
    base: dict[str, object] = dict(
        seed=7,
        weather="rain",
        perception_mode="sensors",
        scenario_name="loop",
        map_name="campus",
        tick_s=0.01,
        duration_s=10.0,
        config={"expected_distance_m": 100.0, "nested": {"k": (1, 2)}},
    )
    base.update(kw)
    return RunMeta(**base)  # type: ignore[arg-type]


def _sample_log() -> RunLog:
    w = RunLogWriter(_meta())
    for i in range(200):
        t = i * 0.02
        steer = float("nan") if i == 3 else 0.01 * i
        w.add_ego_row(t, 1.5 * t, 0.25, 0.1, 1.5, 0.0, steer, i % len(STATE_NAMES), 1.5 * t)
    w.add_agent_rows(0.0, [4, 9], np.array([[10.0, 1.0], [20.0, -2.0]]))
    w.add_agent_rows(0.5, np.array([4]), [[10.5, 1.0]])
    w.add_localization_row(0.0, 0.1, 0.2, 0.1, 5.0, 0.1, -1, 0.0, 0.25, 0.1, 0.25, float("nan"))
    w.add_localization_row(0.1, 0.2, 0.3, 0.1, 0.05, 0.01, 0, 0.15, 0.25, 0.1, 0.25, 0.01)
    w.add_event(2.0, "takeover", reason="stall")
    w.add_event(1.0, "collision", agent_id=np.int64(4), agent_class="car", at_fault=True, ego_speed_mps=1.5)
    w.add_event(1.5, "state_change", **{"from": "normal_driving", "to": "pullover", "reason": "stop S1"})
    w.add_event(3.0, "custom_note", values=(1, 2.5))
    w.set_timing({"modules": {"planning": {"p50_ms": 3.0, "p95_ms": 5.0, "max_ms": 9.0, "calls": 40}}})
    return w.finish()


def test_state_names_follow_behaviour_state_order() -> None:
    assert tuple(s.value for s in BehaviourState) == STATE_NAMES


def test_save_then_load_reads_back_the_same_log(tmp_path: Path) -> None:
    log = _sample_log()
    log.save(tmp_path)
    assert {p.name for p in tmp_path.iterdir()} == {RUN_LOG_FILE, EGO_FILE, AGENTS_FILE, LOCALIZATION_FILE}
    back = RunLog.load(tmp_path)
    assert back == log
    assert len(back.localization) == 2 and np.isnan(back.localization.column("path_d_m")[0])
    assert np.isnan(back.column("steer_front_rad")[3])
    assert back.agents.xy_m.dtype == np.float32 and len(back.agents) == 3
    assert back.timing["modules"]["planning"]["calls"] == 40
    assert back.meta.config["nested"]["k"] == [1, 2]


def test_log_differs_after_a_changed_sample(tmp_path: Path) -> None:
    log = _sample_log()
    ego = log.ego.copy()
    ego[5, 1] += 1e-9
    other = RunLog(meta=log.meta, ego=ego, events=log.events, agents=log.agents, timing=log.timing)
    assert other != log


def test_events_are_sorted_by_time_and_selectable_by_kind() -> None:
    log = _sample_log()
    assert [e.t_s for e in log.events] == [1.0, 1.5, 2.0, 3.0]
    assert [e.kind for e in log.events_of("takeover", "collision")] == ["collision", "takeover"]
    # NumPy scalars become plain Python numbers so that the JSON round trip is exact.
    assert type(log.events_of("collision")[0].data["agent_id"]) is int
    assert log.events_of("custom_note")[0].data == {"values": [1, 2.5]}


def test_ego_array_is_read_only_with_named_columns() -> None:
    log = _sample_log()
    assert log.ego.shape == (200, len(EGO_COLUMNS)) and log.ego.dtype == np.float64
    with pytest.raises(ValueError):
        log.ego[0, 0] = 1.0
    np.testing.assert_allclose(log.column("x_m")[:3], [0.0, 0.03, 0.06])
    with pytest.raises(RunLogError, match="expected one of"):
        log.column("speed")


def test_writer_rejects_time_that_does_not_advance() -> None:
    w = RunLogWriter(_meta())
    w.add_ego_row(0.0, 0, 0, 0, 0, 0, 0, 0, 0)
    with pytest.raises(RunLogError, match=r"expected t_s > 0.0, got 0.0"):
        w.add_ego_row(0.0, 0, 0, 0, 0, 0, 0, 0, 0)
    with pytest.raises(RunLogError, match="got nan"):
        w.add_ego_row(float("nan"), 0, 0, 0, 0, 0, 0, 0, 0)


def test_writer_rejects_non_finite_pose_and_bad_state_codes() -> None:
    w = RunLogWriter(_meta())
    w.add_ego_row(0.0, 0, float("inf"), 0, 0, 0, 0, 0, 0)
    with pytest.raises(RunLogError, match="expected finite y_m"):
        w.finish()
    w = RunLogWriter(_meta())
    w.add_ego_row(0.0, 0, 0, 0, 0, 0, 0, 6, 0)
    with pytest.raises(RunLogError, match=r"state_code an integer in \[-1, 5\], got 6.0"):
        w.finish()


def test_writer_refuses_rows_after_finish() -> None:
    w = RunLogWriter(_meta())
    w.add_ego_row(0.0, 0, 0, 0, 0, 0, 0, -1, 0)
    w.finish()
    with pytest.raises(RunLogError, match="finish"):
        w.add_ego_row(1.0, 0, 0, 0, 0, 0, 0, -1, 0)


@pytest.mark.parametrize(
    ("kind", "data", "message"),
    [
        ("collision", {"agent_id": 1, "agent_class": "car", "at_fault": True}, "field 'ego_speed_mps'"),
        ("collision", {"agent_id": 1.5, "agent_class": "car", "at_fault": True, "ego_speed_mps": 1.0}, "int"),
        ("takeover", {"reason": 3}, r"takeover.reason expected str, got 3"),
        ("intersection_entry", {"order_ok": 1}, "expected bool"),
        ("min_ttc", {"ttc_s": float("nan"), "agent_id": 1}, "JSON-able"),
        ("custom", {"value": object()}, "JSON-able"),
    ],
)
def test_event_with_wrong_fields_is_rejected(kind: str, data: dict[str, object], message: str) -> None:
    w = RunLogWriter(_meta())
    with pytest.raises(RunLogError, match=message):
        w.add_event(0.0, kind, **data)


def test_agent_rows_with_mismatched_shapes_are_rejected() -> None:
    w = RunLogWriter(_meta())
    with pytest.raises(RunLogError, match=r"expected xy of shape \(2, 2\), got \(1, 2\)"):
        w.add_agent_rows(0.0, [1, 2], [[0.0, 0.0]])


def test_meta_rejects_bad_values() -> None:
    with pytest.raises(RunLogError, match="tick_s: expected a finite number > 0, got 0"):
        _meta(tick_s=0)
    with pytest.raises(RunLogError, match="seed: expected an integer"):
        _meta(seed="1")
    with pytest.raises(RunLogError, match="config"):
        _meta(config={"x": float("nan")})


def test_missing_files_raise_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(RunLogError, match=RUN_LOG_FILE):
        RunLog.load(tmp_path)
    _sample_log().save(tmp_path)
    (tmp_path / EGO_FILE).unlink()
    with pytest.raises(RunLogError, match=EGO_FILE):
        RunLog.load(tmp_path)


@pytest.mark.parametrize(
    ("name", "payload", "message"),
    [
        (RUN_LOG_FILE, b"{not json", "unreadable"),
        (RUN_LOG_FILE, b'{"format": "other"}', "expected format"),
        (EGO_FILE, b"garbage", EGO_FILE),
        (AGENTS_FILE, b"", AGENTS_FILE),
    ],
)
def test_garbled_files_raise_a_lastmile_error(
    tmp_path: Path, name: str, payload: bytes, message: str
) -> None:
    _sample_log().save(tmp_path)
    (tmp_path / name).write_bytes(payload)
    with pytest.raises(LastmileError, match=message):
        RunLog.load(tmp_path)


def test_event_with_broken_schema_on_disk_is_rejected(tmp_path: Path) -> None:
    _sample_log().save(tmp_path)
    doc = json.loads((tmp_path / RUN_LOG_FILE).read_text())
    doc["events"][0]["data"].pop("at_fault")
    (tmp_path / RUN_LOG_FILE).write_text(json.dumps(doc))
    with pytest.raises(RunLogError, match=r"events\[0\].*at_fault"):
        RunLog.load(tmp_path)


def test_ego_with_wrong_shape_on_disk_is_rejected(tmp_path: Path) -> None:
    _sample_log().save(tmp_path)
    np.savez(tmp_path / EGO_FILE, ego=np.zeros((4, 3)))
    with pytest.raises(RunLogError, match=r"expected an \(N, 9\) ego array, got shape \(4, 3\)"):
        RunLog.load(tmp_path)


def test_empty_writer_gives_an_empty_log(tmp_path: Path) -> None:
    log = RunLogWriter(_meta()).finish()
    assert log.ego.shape == (0, 9) and log.events == () and len(log.agents) == 0
    log.save(tmp_path)
    assert RunLog.load(tmp_path) == log


def test_referee_event_triples_are_added_as_they_come() -> None:
    w = RunLogWriter(_meta())
    w.add_events([(0.5, "min_ttc", {"ttc_s": 1.5, "agent_id": 3}), (0.2, "loop_completed", {"loop": 1})])
    log = w.finish()
    assert [(e.t_s, e.kind) for e in log.events] == [(0.2, "loop_completed"), (0.5, "min_ttc")]
    w = RunLogWriter(_meta())
    with pytest.raises(RunLogError, match="loop_completed event expected field 'loop'"):
        w.add_events([(0.2, "loop_completed", {"laps": 1})])


def test_a_run_directory_from_before_the_localization_table_reads_with_an_empty_one(tmp_path: Path) -> None:
    log = _sample_log()
    log.save(tmp_path)
    (tmp_path / LOCALIZATION_FILE).unlink()
    back = RunLog.load(tmp_path)
    assert len(back.localization) == 0 and len(back) == len(log)


def test_a_valid_estimate_without_a_position_is_refused_naming_the_column() -> None:
    w = RunLogWriter(_meta())
    w.add_ego_row(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0.0)
    w.add_localization_row(0.0, float("nan"), 0.2, 0.1, 0.05, 0.01, 0, 0.0, 0.2, 0.1, 0.2, 0.0)
    with pytest.raises(RunLogError, match="expected finite est_x_m, got nan in row 0"):
        w.finish()


def test_localization_rows_going_back_in_time_are_refused() -> None:
    w = RunLogWriter(_meta())
    for t in (0.2, 0.1):
        w.add_localization_row(t, 0.1, 0.2, 0.1, 0.05, 0.01, 0, 0.0, 0.2, 0.1, 0.2, 0.0)
    with pytest.raises(RunLogError, match=r"expected strictly increasing t_s, got 0\.1 after 0\.2"):
        w.finish()
