"""aUToTrack: lifecycle, radar velocity, heading flips, camera class evidence, and rollback."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lastmile.core.boxes3d import DetectedBoxes
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.tracking.autotrack import AutoTrack, AutoTrackConfig, ClassParams, default_class_params

CAR = int(ObjectClass.CAR)
PED = int(ObjectClass.PEDESTRIAN)


def _msg(
    t_s: float,
    xy: list[tuple[float, float]],
    *,
    cls: int = CAR,
    yaw: float = 0.0,
    score: float = 5.0,
    source: str = "lidar",
    velocity: list[tuple[float, float]] | None = None,
) -> DetectedBoxes:
    n = len(xy)
    size = (4.0, 1.8, 1.5) if cls == CAR else (0.6, 0.6, 1.7)
    boxes = np.array([[x, y, 0.75, *size, yaw] for x, y in xy]).reshape(n, 7)
    return DetectedBoxes(
        stamp=Stamp(round(t_s * 1e6)),
        frame="map",
        source=source,
        boxes=boxes,
        class_id=np.full(n, cls),
        score=np.full(n, score),
        velocity_mps=np.array(velocity if velocity else [(0.0, 0.0)] * n).reshape(n, 2),
        has_velocity=np.full(n, velocity is not None),
        attributes=np.zeros((n, 0)),
    )


def _config(**car: float) -> AutoTrackConfig:
    classes = default_class_params()
    classes[CAR] = replace(classes[CAR], **car)
    return AutoTrackConfig(classes=classes)


def test_trial_track_is_published_only_after_t_birth() -> None:
    tr = AutoTrack(_config(t_birth_s=0.2, t_expire_s=0.0, t_prune_s=0.3))
    tr.update(_msg(0.0, [(10.0, 0.0)]))
    tr.update(_msg(0.1, [(11.0, 0.0)]))
    assert len(tr.tracks(Stamp(100_000))) == 0 and len(tr) == 1
    tr.update(_msg(0.2, [(12.0, 0.0)]))
    out = tr.tracks(Stamp(200_000))
    assert len(out) == 1 and out.updated[0]
    for k in range(3, 10):
        tr.update(_msg(0.1 * k, [(10.0 + k, 0.0)]))
    assert tr.tracks(Stamp(900_000)).table[0, 7] == pytest.approx(10.0, abs=0.5)  # 1 m per 0.1 s


def test_full_track_is_demoted_after_t_expire_and_pruned_after_t_prune() -> None:
    tr = AutoTrack(_config(t_birth_s=0.0, t_expire_s=0.15, t_prune_s=0.35))
    tr.update(_msg(0.0, [(10.0, 0.0)]))
    assert len(tr.tracks(Stamp(0))) == 1
    for k, expect_published in ((1, 1), (2, 0), (3, 0)):
        tr.update(_msg(0.1 * k, []))
        assert len(tr.tracks(Stamp(100_000 * k))) == expect_published
    assert len(tr) == 1  # demoted but alive
    tr.update(_msg(0.4, []))
    assert len(tr) == 0  # pruned


def test_a_lagging_source_holds_back_demotion_until_it_has_been_silent_for_source_timeout() -> None:
    # The car is seen only by the "front" radar; "rear" sees nothing but keeps stamping frames.
    tr = AutoTrack(replace(_config(t_birth_s=0.0, t_expire_s=0.15, t_prune_s=0.35), source_timeout_s=0.5))
    tr.update(_msg(0.0, [(10.0, 0.0)], source="front"))
    for k in range(1, 5):  # rear reports up to 0.4 s; front's frames after 0.0 have not arrived
        tr.update(_msg(0.1 * k, [], source="rear"))
    # Undetected over time "front" has not reported yet is not "undetected": still published.
    assert len(tr.tracks(Stamp(400_000))) == 1
    # Once "front" has been silent for more than source_timeout_s, the track is demoted, then pruned.
    tr.update(_msg(0.6, [], source="rear"))
    assert len(tr.tracks(Stamp(600_000))) == 0 and len(tr) == 0
    # A single source behaves as before: judged at the message's own stamp.
    one = AutoTrack(_config(t_birth_s=0.0, t_expire_s=0.15, t_prune_s=0.35))
    one.update(_msg(0.0, [(10.0, 0.0)], source="front"))
    one.update(_msg(0.2, [], source="front"))
    assert len(one.tracks(Stamp(200_000))) == 0 and len(one) == 1


def test_demoted_track_comes_back_with_its_id() -> None:
    tr = AutoTrack(_config(t_birth_s=0.0, t_expire_s=0.0, t_prune_s=0.5))
    tr.update(_msg(0.0, [(10.0, 0.0)]))
    first = int(tr.tracks(Stamp(0)).ids[0])
    tr.update(_msg(0.1, []))
    assert len(tr.tracks(Stamp(100_000))) == 0
    tr.update(_msg(0.2, [(10.0, 0.0)]))
    assert tr.tracks(Stamp(200_000)).ids.tolist() == [first]


def test_low_score_detections_update_but_do_not_start_tracks() -> None:
    tr = AutoTrack(_config(t_birth_s=0.0, birth_min_score=1.0))
    tr.update(_msg(0.0, [(10.0, 0.0)], score=0.5))
    assert len(tr) == 0
    tr.update(_msg(0.1, [(10.0, 0.0)], score=2.0))
    tr.update(_msg(0.2, [(10.0, 0.0)], score=0.5))
    out = tr.tracks(Stamp(200_000))
    assert len(out) == 1 and out.score[0] == 0.5


def test_doubtful_detections_are_published_only_once_their_summed_scores_reach_birth_min_evidence() -> None:
    cfg = _config(t_birth_s=0.0, birth_min_evidence=3.0)
    doubtful = AutoTrack(cfg)
    published = []
    for k in range(5):  # 1.0 per detection: evidence 1, 2, 3, ...
        doubtful.update(_msg(0.1 * k, [(10.0, 0.0)], score=1.0))
        published.append(len(doubtful.tracks(Stamp(100_000 * k))))
    assert published == [0, 0, 1, 1, 1]
    confident = AutoTrack(cfg)
    confident.update(_msg(0.0, [(10.0, 0.0)], score=3.5))
    assert len(confident.tracks(Stamp(0))) == 1
    # Negative scores count against the track; the rule is off by default.
    negative = AutoTrack(cfg)
    for k in range(5):
        negative.update(_msg(0.1 * k, [(10.0, 0.0)], score=-0.5))
    assert len(negative.tracks(Stamp(400_000))) == 0
    default = AutoTrack(_config(t_birth_s=0.0))
    default.update(_msg(0.0, [(10.0, 0.0)], score=-0.5))
    assert len(default.tracks(Stamp(0))) == 1


def test_track_score_reports_last_detection_summed_evidence_or_shrunk_mean() -> None:
    scores = (2.0, 4.0, 0.5)

    def published(mode: str) -> float:
        tr = AutoTrack(replace(_config(t_birth_s=0.0), track_score=mode))
        for k, s in enumerate(scores):
            tr.update(_msg(0.1 * k, [(10.0, 0.0)], score=s))
        out = tr.tracks(Stamp(200_000))
        assert len(out) == 1
        return float(out.score[0])

    assert published("last") == 0.5
    assert published("evidence") == pytest.approx(6.5)
    assert published("mean") == pytest.approx(6.5 / 4.0)  # three detections and one at even odds
    # Evidence ranks a long run of modest detections above a short burst of a high one, which "last"
    # and a plain mean would not.
    long_run = AutoTrack(replace(_config(t_birth_s=0.0), track_score="evidence"))
    burst = AutoTrack(replace(_config(t_birth_s=0.0), track_score="evidence"))
    for k in range(10):
        long_run.update(_msg(0.1 * k, [(10.0, 0.0)], score=1.0))
    burst.update(_msg(0.8, [(10.0, 0.0)], score=4.0))
    burst.update(_msg(0.9, [(10.0, 0.0)], score=4.0))
    assert long_run.tracks(Stamp(900_000)).score[0] > burst.tracks(Stamp(900_000)).score[0]
    # The coasting penalty applies on top in every mode.
    tr = AutoTrack(replace(_config(t_birth_s=0.0, t_expire_s=0.3, t_prune_s=0.5), track_score="evidence"))
    tr.update(_msg(0.0, [(10.0, 0.0)], score=2.0))
    assert tr.tracks(Stamp(200_000)).score[0] == pytest.approx(2.0 - 0.2 * 5.0)


def test_the_refined_track_score_is_the_log_odds_of_benbarkas_multiplicative_update() -> None:
    def published(scores: tuple[float, ...]) -> float:
        tr = AutoTrack(replace(_config(t_birth_s=0.0), track_score="refined"))
        for k, s in enumerate(scores):
            tr.update(_msg(0.1 * k, [(10.0, 0.0)], score=s))
        out = tr.tracks(Stamp(round(0.1 * (len(scores) - 1) * 1e6)))
        assert len(out) == 1
        return float(out.score[0])

    def sigmoid(x: float) -> float:
        return 1.0 / (1.0 + np.exp(-x))

    # c <- 1 - (1 - c)(1 - p) from p = sigmoid(score), published as log-odds.
    c = 1.0 - (1.0 - sigmoid(2.0)) * (1.0 - sigmoid(-1.0)) * (1.0 - sigmoid(0.5))
    assert published((2.0, -1.0, 0.5)) == pytest.approx(np.log(c / (1.0 - c)), rel=1e-12)
    assert published((2.0,)) == pytest.approx(2.0, rel=1e-12)  # one detection: its own score
    # A doubtful detection never lowers the confidence (the summed evidence would drop by 3).
    assert published((2.0, -3.0)) > published((2.0,))
    # Long confident tracks stay finite and ordered (no overflow of the probability).
    assert np.isfinite(published((40.0,) * 5)) and published((40.0,) * 5) > published((40.0,) * 4)


def test_radar_doppler_velocity_sets_the_track_velocity_at_once() -> None:
    tr = AutoTrack(_config(t_birth_s=0.0))
    tr.update(_msg(0.0, [(10.0, 0.0)], velocity=[(3.0, -1.0)]))
    out = tr.tracks(Stamp(0))
    assert out.table[0, 7:9] == pytest.approx([3.0, -1.0], abs=1e-9)
    # Predicted a second ahead, the box moved with that velocity.
    assert tr.tracks(Stamp(1_000_000)).table[0, 0:2] == pytest.approx([13.0, -1.0], abs=1e-6)


def test_heading_flipped_by_the_detector_does_not_flip_the_track() -> None:
    tr = AutoTrack(_config(t_birth_s=0.0))
    tr.update(_msg(0.0, [(10.0, 0.0)], yaw=0.1))
    for k in range(1, 6):
        tr.update(_msg(0.1 * k, [(10.0, 0.0)], yaw=0.1 + (np.pi if k % 2 else 0.0)))
    assert tr.tracks(Stamp(500_000)).table[0, 6] == pytest.approx(0.1, abs=0.05)


def test_class_disagreement_keeps_objects_apart_and_hmm_follows_repeated_evidence() -> None:
    tr = AutoTrack(_config(t_birth_s=0.0))
    tr.update(_msg(0.0, [(10.0, 0.0)], cls=PED))
    for k in range(1, 8):
        tr.update(_msg(0.1 * k, [(10.0, 0.0)], cls=CAR if k > 1 else PED))
    out = tr.tracks(Stamp(700_000))
    assert ObjectClass(int(out.class_id[0])) is ObjectClass.CAR
    assert np.allclose(out.class_prob.sum(axis=1), 1.0)


def test_camera_detection_changes_the_class_only() -> None:
    tr = AutoTrack(_config(t_birth_s=0.0))
    tr.update(_msg(0.0, [(10.0, 0.0)], cls=CAR))
    before = tr.tracks(Stamp(0))
    # Camera at the origin looking along +x: optical z = x, optical x = -y, optical y = -z.
    cam_from_map = np.array(
        [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0, 0, 0, 1.0]]
    )
    k = np.array([[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]])
    from lastmile.tracking.class_hmm import project_boxes

    image_box = project_boxes(before.table[:, :7], cam_from_map, k)
    for _ in range(4):
        assert tr.update_classes_from_camera(Stamp(0), image_box, np.array([PED]), cam_from_map, k) == 1
    after = tr.tracks(Stamp(0))
    assert ObjectClass(int(after.class_id[0])) is ObjectClass.PEDESTRIAN
    assert np.array_equal(after.table, before.table)
    # A camera box elsewhere in the image matches nothing.
    far = np.array([[0.0, 0.0, 20.0, 20.0]])
    assert tr.update_classes_from_camera(Stamp(0), far, np.array([CAR]), cam_from_map, k) == 0


def _scene(seed: int) -> list[DetectedBoxes]:
    """Three objects seen by two LiDARs (10 Hz, 50 ms apart) and a radar with Doppler velocity."""
    rng = np.random.default_rng(seed)
    start = np.array([[0.0, 0.0], [20.0, 5.0], [5.0, -8.0]])
    vel = np.array([[5.0, 0.0], [-3.0, 1.0], [0.0, 2.0]])
    msgs = []
    for k in range(30):
        for source, offset in (("lidar_front", 0.0), ("lidar_rear", 0.05), ("radar", 0.025)):
            t = 0.1 * k + offset
            pos = start + vel * t + rng.normal(0.0, 0.1, start.shape)
            velocity = [tuple(v) for v in vel] if source == "radar" else None
            msgs.append(_msg(t, [tuple(p) for p in pos], source=source, velocity=velocity))
    return msgs


def test_shuffled_arrival_gives_the_same_tracks_as_ordered_arrival() -> None:
    msgs = _scene(0)
    ordered = AutoTrack(AutoTrackConfig())
    for m in msgs:
        ordered.update(m)
    # Each message arrives up to 0.4 s late, in random order.
    rng = np.random.default_rng(1)
    arrival = np.array([m.stamp for m in msgs]) + rng.uniform(0, 400_000, len(msgs))
    shuffled = AutoTrack(AutoTrackConfig())
    for i in np.argsort(arrival):
        shuffled.update(msgs[i])
    assert shuffled.rollbacks > 0 and shuffled.late_beyond_window == 0
    stamp = Stamp(3_000_000)
    a, b = ordered.tracks(stamp), shuffled.tracks(stamp)
    assert len(a) == 3
    assert a.ids.tolist() == b.ids.tolist()
    assert np.allclose(a.table, b.table, atol=1e-9)
    assert np.allclose(a.class_prob, b.class_prob)


def test_bad_messages_and_configs_are_refused() -> None:
    with pytest.raises(MessageError, match="class_id"):
        DetectedBoxes(
            stamp=Stamp(0),
            frame="map",
            source="x",
            boxes=np.zeros((1, 7)),
            class_id=np.array([42]),
            score=np.zeros(1),
            velocity_mps=np.zeros((1, 2)),
            has_velocity=np.zeros(1, bool),
            attributes=np.zeros((1, 0)),
        )
    with pytest.raises(MessageError, match="attributes"):
        AutoTrack(n_attributes=2).update(_msg(0.0, [(0.0, 0.0)]))
    with pytest.raises(ConfigError, match="t_prune_s"):
        ClassParams(t_expire_s=1.0, t_prune_s=0.5)
    with pytest.raises(ConfigError, match="missing"):
        AutoTrackConfig(classes={CAR: ClassParams()})
    with pytest.raises(ConfigError, match=r"track_score.*'median'"):
        AutoTrackConfig(track_score="median")
