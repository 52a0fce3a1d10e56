"""aUToTrack rollback: live output and camera evidence under out-of-order arrival equal in-order delivery."""

from __future__ import annotations

import numpy as np

from lastmile.core.boxes3d import DetectedBoxes
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.tracking.autotrack import AutoTrack
from lastmile.tracking.class_hmm import project_boxes
from tests.tracking import sim_scene
from tests.tracking.test_autotrack import CAR, PED, _config, _msg


def _live_ids_of_object(msgs: list[DetectedBoxes], order: list[int]) -> tuple[list[int], AutoTrack]:
    """Feed ``msgs`` in ``order``; after each, the published id of the track near the walking object."""
    tr = AutoTrack()
    ids = []
    newest = 0
    for i in order:
        tr.update(msgs[i])
        newest = max(newest, int(msgs[i].stamp))
        out = tr.tracks(Stamp(newest))
        near = np.abs(out.table[:, 1]) < 1.0
        assert np.count_nonzero(near) == 1
        ids.append(int(out.ids[near][0]))
    return ids, tr


def test_a_late_frame_that_restarts_the_track_does_not_change_its_published_id() -> None:
    # Sensors "a" and "b" stamp at the same instants; a pedestrian (published at its first detection)
    # walks along x. a's first frame also holds clutter far away, in the row before the pedestrian.
    msgs = [_msg(0.0, [(30.0, 30.0), (10.0, 0.0)], cls=PED, source="a")]
    msgs.append(_msg(0.0, [(10.05, 0.0)], cls=PED, source="b"))
    for k in range(1, 6):
        for src in ("a", "b"):
            msgs.append(_msg(0.1 * k, [(10.0 + 0.1 * k, 0.0)], cls=PED, source=src))
    ordered_ids, ordered = _live_ids_of_object(msgs, list(range(len(msgs))))
    # a's first frame arrives after b's: b's detection starts the track and it is published; the late
    # frame then sorts first (same stamp, "a" < "b"), so the replay starts the track from a's row 1,
    # after the clutter's birth. A birth counter would renumber it; the published id must not change.
    shuffled_ids, shuffled = _live_ids_of_object(msgs, [1, 0, *range(2, len(msgs))])
    assert shuffled.rollbacks == 1
    assert len(set(ordered_ids)) == 1
    assert len(set(shuffled_ids)) == 1
    assert shuffled.published_ids.inherited == 1 and ordered.published_ids.inherited == 0
    end = Stamp(500_000)
    np.testing.assert_array_equal(ordered.tracks(end).table, shuffled.tracks(end).table)


def test_camera_class_evidence_is_replayed_by_a_rollback_and_late_evidence_rolls_back() -> None:
    tr0 = AutoTrack(_config(t_birth_s=0.0))
    tr0.update(_msg(0.0, [(10.0, 0.0)], cls=CAR))
    cam_from_map = np.array(
        [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0, 0, 0, 1.0]]
    )
    k = np.array([[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]])
    image_box = project_boxes(tr0.tracks(Stamp(0)).table[:, :7], cam_from_map, k)

    def camera(tr: AutoTrack, t_s: float) -> int:
        return tr.update_classes_from_camera(
            Stamp(round(t_s * 1e6)), image_box, np.array([PED]), cam_from_map, k
        )

    # In capture order: LiDAR 0.00, 0.02 (second LiDAR), camera 0.05 x4, LiDAR 0.10.
    ordered = AutoTrack(_config(t_birth_s=0.0))
    ordered.update(_msg(0.0, [(10.0, 0.0)], cls=CAR))
    ordered.update(_msg(0.02, [(10.0, 0.0)], cls=CAR, source="lidar2"))
    assert [camera(ordered, 0.05) for _ in range(4)] == [1, 1, 1, 1]
    ordered.update(_msg(0.1, [(10.0, 0.0)], cls=CAR))
    # Out of order: the second LiDAR's frame arrives after the camera's (the rollback must replay the
    # camera evidence), and the camera frames after the LiDAR at 0.10 (they roll back themselves).
    shuffled = AutoTrack(_config(t_birth_s=0.0))
    shuffled.update(_msg(0.0, [(10.0, 0.0)], cls=CAR))
    assert [camera(shuffled, 0.05) for _ in range(2)] == [1, 1]
    shuffled.update(_msg(0.1, [(10.0, 0.0)], cls=CAR))
    assert [camera(shuffled, 0.05) for _ in range(2)] == [1, 1]
    shuffled.update(_msg(0.02, [(10.0, 0.0)], cls=CAR, source="lidar2"))
    assert shuffled.rollbacks == 3
    a, b = ordered.tracks(Stamp(100_000)), shuffled.tracks(Stamp(100_000))
    assert ObjectClass(int(a.class_id[0])) is ObjectClass.PEDESTRIAN
    np.testing.assert_array_equal(a.class_prob, b.class_prob)
    np.testing.assert_array_equal(a.table, b.table)


def test_ids_handed_over_by_replays_stay_unique_among_published_tracks() -> None:
    rec = sim_scene.record(seed=1, seconds=10.0, weather="rain")
    res = sim_scene.feed(rec, sim_scene.deliveries(rec, "shuffled", 1), rollback=True)
    assert res.inherited > 0  # replays did hand ids over
    for ids, _ in res.published.values():
        assert len(set(ids.tolist())) == ids.size
