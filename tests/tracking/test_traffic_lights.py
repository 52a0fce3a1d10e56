"""Traffic-light tracker: HMM filtering, duty-cycle flashing, N_birth/N_death lifecycle, input errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import (
    LightState,
    MapTrafficLight,
    TrafficLightDetections,
    TrafficLightStates,
)
from lastmile.tracking import traffic_light_fusion as fusion
from lastmile.tracking import traffic_light_state as hmm
from lastmile.tracking.traffic_lights import TrafficLightTracker, TrafficLightTrackerConfig

CAMERA = PinholeCamera.from_fov("front", 1280, 720, 60.0, x_m=1.5, y_m=0.0, z_m=1.6)
POSE = SE2(0.0, 0.0, 0.0)
R, Y, G, OFF = (int(s) for s in LightState)
FRAME_US = 66_667  # 15 Hz camera


def _light(light_id: str = "L1", x_m: float = 40.0, y_m: float = 0.0) -> MapTrafficLight:
    return MapTrafficLight(
        light_id=light_id, x_m=x_m, y_m=y_m, z_m=4.5, facing_rad=math.pi, signal_id=7, stop_line_id=3,
        stop_x_m=x_m - 10.0, stop_y_m=y_m,
    )  # fmt: skip


def _frame(k: int, lights: tuple[MapTrafficLight, ...], states: list[int], score: float = 0.9):
    """Detections of ``lights`` (those visible) in ``states`` at frame ``k``; a state < 0 is a miss."""
    proj = fusion.project_lights(CAMERA, fusion.light_positions(lights), POSE, 70.0, math.radians(60.0))
    boxes, det_states = [], []
    for row, idx in enumerate(proj.indices.tolist()):
        if states[idx] < 0:
            continue
        boxes.append(proj.boxes[row] + np.array([2.0, -1.0, 2.0, -1.0]))  # a detector is a few pixels off
        det_states.append(states[idx])
    return TrafficLightDetections(
        stamp=Stamp(k * FRAME_US), camera_id="front", boxes=np.array(boxes).reshape(-1, 4),
        states=np.array(det_states, dtype=np.int64), scores=np.full(len(boxes), score),
    )  # fmt: skip


def _run(tracker: TrafficLightTracker, sequence: list[int], start: int = 0) -> TrafficLightStates:
    for k, s in enumerate(sequence):
        tracker.update(_frame(start + k, tracker.lights, [s]), POSE)
    return tracker.states()


def test_map_light_projects_near_image_centre_ahead_of_camera() -> None:
    proj = fusion.project_lights(CAMERA, fusion.light_positions((_light(),)), POSE, 70.0, math.radians(60.0))
    assert proj.indices.tolist() == [0]
    cx = 0.5 * (proj.boxes[0, 0] + proj.boxes[0, 2])
    cy = 0.5 * (proj.boxes[0, 1] + proj.boxes[0, 3])
    assert cx == pytest.approx(640.0, abs=1e-6)
    assert cy < 360.0  # above the horizon: the head is higher than the camera
    # width 0.35 m at 38.5 m depth, f = 1108.5 px
    assert proj.boxes[0, 2] - proj.boxes[0, 0] == pytest.approx(1108.5 * 0.35 / 38.5, rel=1e-3)


def test_lights_behind_beyond_range_or_facing_away_are_not_expected() -> None:
    behind = _light("behind", x_m=-20.0)
    far = _light("far", x_m=120.0)
    away = MapTrafficLight(light_id="away", x_m=30.0, y_m=0.0, z_m=4.5, facing_rad=0.0)
    proj = fusion.project_lights(
        CAMERA, fusion.light_positions((behind, far, away, _light())), POSE, 70.0, math.radians(60.0)
    )
    assert proj.indices.tolist() == [3]


def test_association_is_gated_and_one_to_one() -> None:
    projected = np.array([[100.0, 100.0, 110.0, 130.0], [300.0, 100.0, 310.0, 130.0]])
    detected = np.array(
        [[301.0, 101.0, 311.0, 131.0], [102.0, 99.0, 112.0, 129.0], [700.0, 100.0, 710.0, 130.0]]
    )
    assert sorted(fusion.associate(projected, detected, gate_px=40.0, iou_weight=1.0)) == [(0, 1), (1, 0)]
    assert fusion.associate(projected, detected[2:], gate_px=40.0, iou_weight=1.0) == []


def test_track_is_born_after_n_birth_successive_frames() -> None:
    tracker = TrafficLightTracker((_light(),), (CAMERA,), TrafficLightTrackerConfig(n_birth=3))
    assert len(_run(tracker, [R, R]).light_ids) == 0
    out = _run(tracker, [R], start=2)
    assert out.light_ids == ("L1",) and out.track_ids.tolist() == [1]
    assert out.stop_line_ids.tolist() == [3] and out.stop_xy_m.tolist() == [[30.0, 0.0]]


def test_a_miss_resets_the_birth_count() -> None:
    tracker = TrafficLightTracker((_light(),), (CAMERA,), TrafficLightTrackerConfig(n_birth=3))
    assert len(_run(tracker, [R, R, -1, R, R]).light_ids) == 0
    assert len(_run(tracker, [R], start=5).light_ids) == 1


def test_track_survives_fewer_than_n_death_misses_and_is_dropped_at_n_death() -> None:
    tracker = TrafficLightTracker((_light(),), (CAMERA,), TrafficLightTrackerConfig(n_birth=2, n_death=5))
    _run(tracker, [G, G, G])
    out = _run(tracker, [-1] * 4, start=3)
    assert out.track_ids.tolist() == [1] and out.frames_since_seen.tolist() == [4]
    assert out.states.tolist() == [G]  # the HMM carries the state through the occlusion
    assert len(_run(tracker, [-1], start=7).light_ids) == 0
    # Re-detected, the light is a new track with a new id after N_birth frames.
    assert _run(tracker, [G, G], start=8).track_ids.tolist() == [2]


def test_hmm_rejects_a_flickering_misclassification() -> None:
    tracker = TrafficLightTracker((_light(),), (CAMERA,))
    seq = [R] * 10 + [G] + [R] * 3 + [Y] + [R] * 3 + [G]
    for k, s in enumerate(seq):
        tracker.update(_frame(k, tracker.lights, [s]), POSE)
        out = tracker.states()
        if len(out.light_ids):
            assert out.states.tolist() == [R], f"frame {k}: a single {LightState(s).name} flipped the state"
    assert out.confidence[0] > 0.9


def test_hmm_follows_a_real_change_within_a_few_frames() -> None:
    tracker = TrafficLightTracker((_light(),), (CAMERA,))
    _run(tracker, [G] * 20)
    changed_at = None
    for k in range(10):
        tracker.update(_frame(20 + k, tracker.lights, [Y]), POSE)
        if tracker.states().states.tolist() == [Y]:
            changed_at = k
            break
    assert changed_at is not None and changed_at <= 3


def test_flashing_red_is_detected_by_duty_cycle() -> None:
    tracker = TrafficLightTracker((_light(),), (CAMERA,))
    # 15 Hz camera, 1 Hz flash lit 60 % of the cycle (9 of 15 frames); the default window of 30 states
    # spans two cycles, so the on ratio is 0.6 whatever the phase.
    seq = [R if (k % 15) < 9 else OFF for k in range(60)]
    out = _run(tracker, seq)
    assert out.flashing.tolist() == [True]
    assert out.states.tolist() == [R]


def test_steady_light_and_a_light_lit_too_long_are_not_flashing() -> None:
    steady = _run(TrafficLightTracker((_light(),), (CAMERA,)), [R] * 60)
    assert steady.flashing.tolist() == [False] and steady.states.tolist() == [R]
    long_on = _run(
        TrafficLightTracker((_light(),), (CAMERA,)), [R if (k % 15) < 12 else OFF for k in range(60)]
    )
    assert long_on.flashing.tolist() == [False]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from([R, Y, G, OFF]), min_size=2, max_size=40))
def test_duty_cycle_flags_exactly_on_ratios_in_the_mutcd_band(history: list[int]) -> None:
    flashing, _ = hmm.duty_cycle(history, 0.5, 2.0 / 3.0)
    on = sum(1 for s in history if s != OFF) / len(history)
    assert flashing == (0.5 - 1e-12 <= on <= 2.0 / 3.0 + 1e-12)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 30.0), st.floats(0.0, 0.5))
def test_transition_matrix_is_row_stochastic_and_favours_the_signal_sequence(
    dt_s: float, p_out: float
) -> None:
    t = hmm.transition_matrix(dt_s, np.array([25.0, 3.5, 25.0, 30.0]), p_out)
    assert np.allclose(t.sum(axis=1), 1.0) and np.all(t >= 0)
    if dt_s > 0:
        assert t[G, Y] >= t[G, R] and t[Y, R] >= t[Y, G] and t[R, G] >= t[R, Y]


def test_detections_from_an_unknown_camera_raise() -> None:
    tracker = TrafficLightTracker((_light(),), (CAMERA,))
    det = TrafficLightDetections(stamp=Stamp(0), camera_id="rear")
    with pytest.raises(MessageError, match="expected one of \\['front'\\], got 'rear'"):
        tracker.update(det, POSE)


def test_malformed_detections_and_configs_raise_specific_errors() -> None:
    with pytest.raises(MessageError, match="LightState values"):
        TrafficLightDetections(stamp=Stamp(0), camera_id="front", boxes=np.ones((1, 4)) * [0, 0, 1, 1],
                               states=np.array([7]), scores=np.array([0.5]))  # fmt: skip
    with pytest.raises(MessageError, match="x1 < x2"):
        TrafficLightDetections(stamp=Stamp(0), camera_id="front", boxes=np.array([[5.0, 0.0, 1.0, 1.0]]),
                               states=np.array([0]), scores=np.array([0.5]))  # fmt: skip
    with pytest.raises(MessageError, match="scores"):
        TrafficLightDetections(stamp=Stamp(0), camera_id="front", boxes=np.array([[0.0, 0.0, 1.0, 1.0]]),
                               states=np.array([0]), scores=np.array([1.5]))  # fmt: skip
    with pytest.raises(ConfigError, match="confusion"):
        TrafficLightTrackerConfig(confusion=((1.0, 0.0, 0.0, 0.0),) * 3)
    with pytest.raises(ConfigError, match="unique light ids"):
        TrafficLightTracker((_light(), _light()), (CAMERA,))
