"""Velocities from where tracks were published, and the off-road unknowns they clear."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.stamp import Stamp
from lastmile.decision.decision_config import DecisionConfig
from lastmile.decision.observed_motion import FORGET_S, observed_velocities, updated_trails
from lastmile.decision.offroad_unknowns import yieldable_tracks

_AGE = TRACK_COLUMNS.index("age_s")


def _track(tid: int, x: float, y: float, vx: float, vy: float, age_s: float) -> TrackedObjects:
    row = [x, y, vx, vy, 0.6, 0.2, 0.0, float(ObjectClass.UNKNOWN), 0.1, age_s]
    return TrackedObjects(stamp=Stamp(0), ids=np.array([tid]), table=np.array([row]))


def test_a_trail_keeps_the_newest_sample_a_window_old_and_gives_the_displacement_over_it():
    trails: dict = {}
    for k in range(16):  # 1.5 s at 10 Hz, moving 0.1 m per cycle along y
        t = k * 0.1
        tracks = _track(5, 10.0, 0.1 * k, 0.0, 1.0, age_s=t)
        trails = updated_trails(trails, tracks, t, window_s=1.0)
        v = observed_velocities(trails, tracks, window_s=1.0)
        if t < 1.0 - 1e-9:
            assert v == {}  # not a window's worth yet: the filter's velocity alone
        else:
            assert v[5] == pytest.approx((0.0, 1.0))
    assert trails[5][0][0] == pytest.approx(0.5)  # the newest sample 1 s old, and the newer ones
    assert len(trails[5]) == 11


def test_a_track_published_now_and_then_is_measured_over_the_gap():
    # Snow seed 0: a sign post's track, coasting unpublished for 8.5 s in between, read 0.67 m/s
    # towards the road; its positions had moved 0.5 m.
    trails = updated_trails({}, _track(9, 165.96, -5.22, 0.0, -0.4, age_s=0.4), 505.1, 1.0)
    now = _track(9, 166.09, -4.80, 0.28, 0.61, age_s=8.9)
    trails = updated_trails(trails, now, 513.6, 1.0)
    vx, vy = observed_velocities(trails, now, 1.0)[9]
    assert np.hypot(vx, vy) == pytest.approx(np.hypot(0.13, 0.42) / 8.5)


def test_a_new_track_with_an_old_id_starts_a_new_trail_and_unseen_trails_are_forgotten():
    trails = updated_trails({}, _track(3, 0.0, 0.0, 0.0, 0.0, age_s=5.0), 10.0, 1.0)
    reborn = _track(3, 50.0, 0.0, 0.0, 0.0, age_s=0.2)  # younger than its id's trail
    trails = updated_trails(trails, reborn, 12.0, 1.0)
    assert trails[3] == ((12.0, 50.0, 0.0),)
    other = _track(4, 0.0, 0.0, 0.0, 0.0, age_s=1.0)
    assert 3 not in updated_trails(trails, other, 12.0 + FORGET_S + 0.1, 1.0)
    assert 3 in updated_trails(trails, other, 12.0 + FORGET_S - 0.1, 1.0)


def test_an_offroad_unknown_is_heading_onto_the_road_only_if_its_positions_bear_it_out(straight_map):
    # 1.3 m off the lane's left edge (y 1.75), filter velocity 0.6 m/s towards it: on the road in 2.2 s.
    post = _track(7, 80.0, 3.3, 0.0, -0.6, age_s=9.0)
    assert len(yieldable_tracks(post, straight_map, 6.0)) == 1
    assert len(yieldable_tracks(post, straight_map, 6.0, {7: (0.0, -0.06)})) == 0  # it stood
    assert len(yieldable_tracks(post, straight_map, 6.0, {7: (0.0, -0.5)})) == 1  # it walked
    # Moving along the road, its filter's velocity is what says it stays off: still dropped.
    along = _track(7, 80.0, 3.3, 1.0, 0.0, age_s=9.0)
    assert len(yieldable_tracks(along, straight_map, 6.0, {7: (0.0, -0.5)})) == 0
    # On the road it is kept whatever it did.
    assert len(yieldable_tracks(_track(7, 80.0, 1.0, 0.0, 0.0, 9.0), straight_map, 6.0, {7: (0.0, 0.0)})) == 1


def test_the_motion_window_must_be_positive():
    with pytest.raises(ConfigError, match="offroad_motion_window_s"):
        DecisionConfig(offroad_motion_window_s=0.0)
