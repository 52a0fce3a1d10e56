import math

import numpy as np
import pytest

from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.sensor_frames import RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.tracking.radar_tracker import RadarObjectTracker

ORIGIN = SE2(0.0, 0.0, 0.0)


def _frame(
    t_s: float, objects: list[tuple[float, float, float, float, float]], sensor: str = "front"
) -> RadarFrame:
    rows = [(x, y, vx, vy, rcs, 0.0) for x, y, vx, vy, rcs in objects]
    return RadarFrame(stamp=Stamp(round(t_s * 1e6)), sensor_id=sensor, objects=np.array(rows).reshape(-1, 6))


def _drive(tracker, frames):
    for f in frames:
        tracker.update(f, ORIGIN, ORIGIN)


def test_constant_velocity_target_is_tracked_within_decimetres():
    rng = np.random.default_rng(0)
    tracker = RadarObjectTracker()
    frames = [
        _frame(
            k * 0.05,
            [
                (
                    10 + 3 * k * 0.05 + rng.normal(0, 0.15),
                    2 + rng.normal(0, 0.15),
                    3 + rng.normal(0, 0.12),
                    rng.normal(0, 0.12),
                    10.0,
                )
            ],
        )
        for k in range(21)
    ]
    _drive(tracker, frames)
    tracks = tracker.tracks(Stamp(1_000_000))
    assert len(tracks) == 1
    x, y, vx, vy = tracks.table[0, :4]
    assert math.hypot(x - 13.0, y - 2.0) < 0.3
    assert math.hypot(vx - 3.0, vy) < 0.3
    assert tracks.table[0, 7] == ObjectClass.CAR


def test_two_crossing_targets_keep_their_ids():
    tracker = RadarObjectTracker()
    ids_before = None
    for k in range(60):
        t = k * 0.05
        tracker.update(
            _frame(t, [(5 + 2 * t, 0.0, 2.0, 0.0, 10.0), (11 - 2 * t, 0.6, -2.0, 0.0, 10.0)]), ORIGIN, ORIGIN
        )
        tracks = tracker.tracks(Stamp(round(t * 1e6)))
        if k == 10:
            ids_before = {int(i): float(row[2]) for i, row in zip(tracks.ids, tracks.table, strict=True)}
    after = {int(i): float(row[2]) for i, row in zip(tracks.ids, tracks.table, strict=True)}
    assert ids_before is not None and set(after) == set(ids_before)
    for tid, vx in after.items():
        assert np.sign(vx) == np.sign(ids_before[tid])


def test_a_one_off_false_alarm_never_becomes_a_track_and_tracks_expire():
    tracker = RadarObjectTracker()
    _drive(
        tracker, [_frame(0.0, [(20.0, 5.0, 0.0, 0.0, -15.0)])] + [_frame(k * 0.05, []) for k in range(1, 10)]
    )
    assert len(tracker.tracks(Stamp(500_000))) == 0
    _drive(tracker, [_frame(1.0 + k * 0.05, [(8.0, 0.0, 0.0, 0.0, 10.0)]) for k in range(5)])
    assert len(tracker.tracks(Stamp(1_200_000))) == 1
    _drive(tracker, [_frame(1.25 + k * 0.05, []) for k in range(1, 20)])
    assert len(tracker.tracks(Stamp(2_200_000))) == 0


def test_a_slow_small_target_is_an_animal_and_stays_tracked_standing_still():
    tracker = RadarObjectTracker()
    _drive(tracker, [_frame(k * 0.05, [(12.0, 0.5, 0.0, 0.0, -16.0)]) for k in range(20)])
    tracks = tracker.tracks(Stamp(1_000_000))
    assert len(tracks) == 1 and tracks.table[0, 7] == ObjectClass.ANIMAL
    assert math.hypot(*tracks.table[0, 2:4]) < 0.2


def test_swapped_frame_order_gives_nearly_the_same_track():
    frames = [
        _frame(k * 0.05, [(10 + 2 * k * 0.05, 1.0, 2.0, 0.0, 10.0)], "front" if k % 2 else "rear")
        for k in range(20)
    ]
    swapped = frames.copy()
    swapped[10], swapped[11] = swapped[11], swapped[10]
    a, b = RadarObjectTracker(), RadarObjectTracker()
    _drive(a, frames)
    _drive(b, swapped)
    ta, tb = a.tracks(Stamp(1_000_000)), b.tracks(Stamp(1_000_000))
    assert np.allclose(ta.table[:, :4], tb.table[:, :4], atol=0.1)


def test_radar_mount_and_pose_are_applied():
    tracker = RadarObjectTracker()
    rear = SE2(-0.85, 0.0, math.pi)
    pose = SE2(100.0, 50.0, math.pi / 2)
    for k in range(5):
        tracker.update(_frame(k * 0.05, [(10.0, 0.0, 0.0, 0.0, 10.0)], "rear"), pose, rear)
    x, y = tracker.tracks(Stamp(200_000)).table[0, :2]
    # Rear radar looks backwards; the vehicle faces north, so the object is 10.85 m south of the axle.
    assert x == pytest.approx(100.0, abs=0.05) and y == pytest.approx(50.0 - 10.85, abs=0.05)
