import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS
from lastmile.core.sensor_frames import RadarFrame
from lastmile.core.stamp import Stamp, stamp_from_s
from lastmile.tracking.radar_tracker import RadarObjectTracker, RadarTrackerConfig

ORIGIN = SE2(0.0, 0.0, 0.0)
COL = {name: i for i, name in enumerate(TRACK_COLUMNS)}
POS_STD, VEL_STD, RCS_STD = 0.15, 0.12, 2.0


def _frame(t_s: float, objects: list[tuple[float, float, float, float, float]], sensor: str = "front"):
    rows = [(x, y, vx, vy, rcs, 0.0) for x, y, vx, vy, rcs in objects]
    return RadarFrame(stamp=stamp_from_s(t_s), sensor_id=sensor, objects=np.array(rows).reshape(-1, 6))


def _noisy(rng, x, y, vx, vy, rcs):
    return (
        x + rng.normal(0, POS_STD),
        y + rng.normal(0, POS_STD),
        vx + rng.normal(0, VEL_STD),
        vy + rng.normal(0, VEL_STD),
        rcs + rng.normal(0, RCS_STD),
    )


def _drive(tracker, frames, pose=ORIGIN, mount=ORIGIN):
    for f in frames:
        tracker.update(f, pose, mount)


def _row(tracks, track_id):
    return tracks.table[list(tracks.ids).index(track_id)]


def test_a_constant_velocity_target_is_tracked_within_decimetres_after_one_second():
    rng = np.random.default_rng(0)
    tracker = RadarObjectTracker()
    frames = [_frame(k * 0.05, [_noisy(rng, 10 + 3 * k * 0.05, 2.0, 3.0, 0.0, 10.0)]) for k in range(21)]
    _drive(tracker, frames)
    tracks = tracker.tracks(Stamp(1_000_000))
    assert len(tracks) == 1
    row = tracks.table[0]
    assert math.hypot(row[COL["x_m"]] - 13.0, row[COL["y_m"]] - 2.0) < 0.3
    assert math.hypot(row[COL["vx_mps"]] - 3.0, row[COL["vy_mps"]]) < 0.3
    assert row[COL["class_id"]] == ObjectClass.CAR
    assert row[COL["yaw_rad"]] == pytest.approx(0.0, abs=0.1)
    assert (row[COL["length_m"]], row[COL["width_m"]]) == (4.5, 1.8)
    assert 0.0 < row[COL["pos_std_m"]] < POS_STD
    assert row[COL["age_s"]] == pytest.approx(1.0)


def test_tracks_are_predicted_to_the_requested_stamp():
    tracker = RadarObjectTracker()
    _drive(tracker, [_frame(k * 0.05, [(10 + 2 * k * 0.05, 0.0, 2.0, 0.0, 10.0)]) for k in range(5)])
    now, later = tracker.tracks(Stamp(200_000)), tracker.tracks(Stamp(500_000))
    assert later.table[0, COL["x_m"]] - now.table[0, COL["x_m"]] == pytest.approx(0.6, abs=1e-6)
    assert later.table[0, COL["pos_std_m"]] > now.table[0, COL["pos_std_m"]]


def test_two_crossing_targets_keep_their_ids():
    # One walks north, the other drives east; they pass the same point at the same time, where only
    # their velocities tell them apart.
    rng = np.random.default_rng(1)
    tracker = RadarObjectTracker()
    first: dict[int, float] = {}
    for k in range(101):
        t = k * 0.05
        north = _noisy(rng, 20.0, -10.0 + 4.0 * t, 0.0, 4.0, -3.0)
        east = _noisy(rng, 10.0 + 4.0 * t, 0.0, 4.0, 0.0, 10.0)
        tracker.update(_frame(t, [north, east] if k % 2 else [east, north]), ORIGIN, ORIGIN)
        if k == 20:
            tracks = tracker.tracks(stamp_from_s(t))
            first = {
                int(i): math.atan2(r[COL["vy_mps"]], r[COL["vx_mps"]])
                for i, r in zip(tracks.ids, tracks.table, strict=True)
            }
    tracks = tracker.tracks(Stamp(5_000_000))
    assert len(first) == 2 and set(map(int, tracks.ids)) == set(first)
    for track_id, heading in first.items():
        row = _row(tracks, track_id)
        assert math.atan2(row[COL["vy_mps"]], row[COL["vx_mps"]]) == pytest.approx(heading, abs=0.2)


def test_a_false_alarm_seen_once_never_becomes_a_confirmed_track():
    tracker = RadarObjectTracker()
    frames = [_frame(0.0, [(20.0, 5.0, 0.3, -0.2, -15.0)])] + [_frame(k * 0.05, []) for k in range(1, 10)]
    for f in frames:
        tracker.update(f, ORIGIN, ORIGIN)
        assert len(tracker.tracks(f.stamp)) == 0
    assert len(tracker) == 0


def test_fresh_clutter_every_frame_confirms_nothing():
    rng = np.random.default_rng(2)
    tracker = RadarObjectTracker()
    for k in range(200):
        clutter = [
            (r * math.cos(a), r * math.sin(a), rng.normal(0, 0.5), rng.normal(0, 0.5), rng.uniform(-20, -5))
            for r, a in zip(rng.uniform(2, 40, 3), rng.uniform(-1.3, 1.3, 3), strict=True)
        ]
        tracker.update(_frame(k * 0.05, clutter), ORIGIN, ORIGIN)
    assert len(tracker.tracks(Stamp(10_000_000))) == 0


def test_a_track_is_deleted_after_t_expire_without_detections():
    tracker = RadarObjectTracker(RadarTrackerConfig(t_expire_s=0.6))
    _drive(tracker, [_frame(k * 0.05, [(8.0, 0.0, 1.0, 0.0, 10.0)]) for k in range(6)])
    assert len(tracker.tracks(Stamp(250_000))) == 1
    # Still reported while coasting, gone once t_expire has passed, even before the next frame.
    assert len(tracker.tracks(Stamp(250_000 + 550_000))) == 1
    assert len(tracker.tracks(Stamp(250_000 + 650_000))) == 0
    _drive(tracker, [_frame(0.25 + k * 0.05, []) for k in range(1, 12)])
    assert len(tracker) == 1
    tracker.update(_frame(0.25 + 12 * 0.05 + 0.01, []), ORIGIN, ORIGIN)
    assert len(tracker) == 0


def test_a_standing_goose_is_an_animal_and_a_parked_car_stays_tracked_at_rest():
    rng = np.random.default_rng(3)
    tracker = RadarObjectTracker()
    for k in range(200):  # 10 s
        goose = _noisy(rng, 12.0 + 0.3 * k * 0.05, 0.5, 0.3, 0.0, -16.0)
        parked_car = _noisy(rng, 25.0, -4.0, 0.0, 0.0, 10.0)
        tracker.update(_frame(k * 0.05, [goose, parked_car]), ORIGIN, ORIGIN)
    tracks = tracker.tracks(Stamp(10_000_000))
    assert len(tracks) == 2
    by_x = sorted(tracks.table.tolist(), key=lambda r: r[COL["x_m"]])
    goose_row, car_row = by_x
    assert goose_row[COL["class_id"]] == ObjectClass.ANIMAL
    assert car_row[COL["class_id"]] == ObjectClass.CAR
    assert math.hypot(car_row[COL["vx_mps"]], car_row[COL["vy_mps"]]) < 0.1
    assert math.hypot(car_row[COL["x_m"]] - 25.0, car_row[COL["y_m"]] + 4.0) < 0.1
    assert goose_row[COL["age_s"]] == pytest.approx(10.0)


def test_pedestrians_and_cyclists_are_told_apart_by_speed_and_odd_returns_stay_unknown():
    rng = np.random.default_rng(4)
    tracker = RadarObjectTracker()
    for k in range(60):
        t = k * 0.05
        pedestrian = _noisy(rng, 10.0, -3.0 + 1.3 * t, 0.0, 1.3, -5.0)
        cyclist = _noisy(rng, 20.0 + 5.0 * t, 6.0, 5.0, 0.0, -2.0)
        in_between = _noisy(rng, 30.0, -8.0, 0.0, 0.0, -10.0)  # as likely a goose as a person
        tracker.update(_frame(t, [pedestrian, cyclist, in_between]), ORIGIN, ORIGIN)
    tracks = tracker.tracks(Stamp(3_000_000))
    classes = {round(r[COL["y_m"]] / 4): r[COL["class_id"]] for r in tracks.table}
    assert classes == {0: ObjectClass.PEDESTRIAN, 2: ObjectClass.CYCLIST, -2: ObjectClass.UNKNOWN}


def test_swapped_frame_order_gives_nearly_the_same_tracks():
    rng = np.random.default_rng(5)
    frames = [
        _frame(
            k * 0.05,
            [
                _noisy(rng, 10 + 2 * k * 0.05, 1.0, 2.0, 0.0, 10.0),
                _noisy(rng, 15.0, -3 + k * 0.05, 0, 1.0, -5),
            ],
            "front" if k % 2 else "rear",
        )
        for k in range(20)
    ]
    swapped = frames.copy()
    for k in (5, 11, 15):
        swapped[k], swapped[k + 1] = swapped[k + 1], swapped[k]
    a, b = RadarObjectTracker(), RadarObjectTracker()
    _drive(a, frames)
    _drive(b, swapped)
    ta, tb = a.tracks(Stamp(1_000_000)), b.tracks(Stamp(1_000_000))
    assert list(ta.ids) == list(tb.ids) and len(ta) == 2
    assert np.allclose(ta.table[:, :4], tb.table[:, :4], atol=0.05)
    assert np.array_equal(ta.table[:, COL["class_id"]], tb.table[:, COL["class_id"]])


def test_a_late_frame_does_not_pull_a_track_back_in_time():
    tracker = RadarObjectTracker()
    _drive(tracker, [_frame(k * 0.05, [(10 + 5 * k * 0.05, 0.0, 5.0, 0.0, 10.0)]) for k in range(10)])
    before = tracker.tracks(Stamp(450_000)).table[0, COL["x_m"]]
    tracker.update(_frame(0.4, [(12.0, 0.0, 5.0, 0.0, 10.0)], "rear"), ORIGIN, ORIGIN)
    after = tracker.tracks(Stamp(450_000)).table[0, COL["x_m"]]
    assert after == pytest.approx(before, abs=0.02) and before == pytest.approx(12.25, abs=0.02)


def test_frames_from_a_radar_that_cannot_see_an_object_do_not_count_against_it():
    tracker = RadarObjectTracker(RadarTrackerConfig(confirm_hits=3, confirm_window=4))
    target = [(30.0, 0.0, 0.0, 0.0, 10.0)]
    # The front radar sees it in 3 of its 4 frames; the rear radar (blind to it) sends empty frames.
    pattern = [("front", target), ("rear", []), ("front", []), ("rear", []), ("front", target)]
    pattern += [("rear", []), ("front", target)]
    _drive(tracker, [_frame(k * 0.025, objects, sensor) for k, (sensor, objects) in enumerate(pattern)])
    assert len(tracker.tracks(Stamp(150_000))) == 1


def test_the_radar_mount_and_the_vehicle_pose_are_applied():
    tracker = RadarObjectTracker()
    rear = SE2(-0.85, 0.0, math.pi)
    pose = SE2(100.0, 50.0, math.pi / 2)
    # 10 m behind the rear radar, moving away from it at 1 m/s (radar frame +x).
    frames = [_frame(k * 0.05, [(10.0 + k * 0.05, 0.0, 1.0, 0.0, 10.0)], "rear") for k in range(5)]
    _drive(tracker, frames, pose, rear)
    row = tracker.tracks(Stamp(200_000)).table[0]
    # The vehicle faces north, so the rear radar looks south: the object is south of the axle.
    assert row[COL["x_m"]] == pytest.approx(100.0, abs=0.05)
    assert row[COL["y_m"]] == pytest.approx(50.0 - 11.05, abs=0.05)
    assert (row[COL["vx_mps"]], row[COL["vy_mps"]]) == pytest.approx((0.0, -1.0), abs=0.05)
    assert row[COL["yaw_rad"]] == pytest.approx(-math.pi / 2, abs=0.05)


def test_live_tracks_never_exceed_max_tracks():
    tracker = RadarObjectTracker(RadarTrackerConfig(max_tracks=5))
    _drive(tracker, [_frame(0.05 * k, [(5.0 * i, 10.0, 0.0, 0.0, 0.0) for i in range(8)]) for k in range(5)])
    assert len(tracker) == 5 and len(tracker.tracks(Stamp(200_000))) == 5


def test_non_finite_objects_and_negative_stamps_raise_message_errors():
    tracker = RadarObjectTracker()
    frame = _frame(0.0, [(1.0, 2.0, 0.0, 0.0, 5.0)])
    object.__setattr__(frame, "objects", np.array([[1.0, np.nan, 0.0, 0.0, 5.0, 0.0]]))
    with pytest.raises(MessageError, match="finite"):
        tracker.update(frame, ORIGIN, ORIGIN)
    with pytest.raises(MessageError, match="non-negative"):
        tracker.update(RadarFrame(stamp=Stamp(-1), sensor_id="front"), ORIGIN, ORIGIN)
    with pytest.raises(MessageError):
        _frame(0.0, [(1.0, math.inf, 0.0, 0.0, 5.0)])
    assert len(tracker) == 0


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"confirm_hits": 6, "confirm_window": 5}, "confirm_hits <= confirm_window"),
        ({"gate_m": 0.0}, "gate_m"),
        ({"t_expire_s": float("nan")}, "t_expire_s"),
        ({"max_tracks": 0}, "max_tracks"),
    ],
)
def test_bad_configs_are_rejected_with_the_field_named(change, match):
    with pytest.raises(ConfigError, match=match):
        RadarTrackerConfig(**change)


def test_a_goose_that_walks_beside_the_front_bumper_is_held_in_the_blind_zone_not_forgotten():
    # The front radar at the origin looks along +x with +-75 deg; the goose walks from ahead of it
    # to beside it (azimuth -80 deg) at 0.25 m/s and stops there, where no radar can see it.
    config = RadarTrackerConfig()
    tracker = RadarObjectTracker(config)
    frames = []
    for k in range(41):
        t = k * 0.05
        y = -0.5 - 0.25 * t
        x = 1.5 - 0.6 * t
        az = math.degrees(math.atan2(y, x))
        frames.append(_frame(t, [(x, y, -0.6, -0.25, -15.0)] if az > -75.0 else []))
    _drive(tracker, frames)
    # Then empty lists for far longer than t_expire_s: it is beside the bumper, out of every view.
    _drive(tracker, [_frame(2.0 + k * 0.05, []) for k in range(1, 61)])
    tracks = tracker.tracks(stamp_from_s(5.0))
    assert len(tracks) == 1
    assert tracks.table[0, COL["x_m"]] < 1.5
    # Held only so long: after blind_zone_hold_s without a detection the track goes.
    _drive(tracker, [_frame(5.0 + k * 0.05, []) for k in range(1, int(config.blind_zone_hold_s / 0.05) + 2)])
    assert len(tracker.tracks(stamp_from_s(5.0 + config.blind_zone_hold_s + 0.1))) == 0


def test_a_track_lost_inside_the_field_of_view_is_not_held():
    tracker = RadarObjectTracker()
    _drive(tracker, [_frame(k * 0.05, [(3.0, 0.5, 0.0, 0.0, -15.0)]) for k in range(10)])
    _drive(tracker, [_frame(0.5 + k * 0.05, []) for k in range(1, 21)])
    assert len(tracker.tracks(stamp_from_s(1.5))) == 0
