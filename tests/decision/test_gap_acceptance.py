"""Gap acceptance arithmetic: arrival times on an approach, standing against moving, the clearance time."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.polyline import Polyline
from lastmile.core.stamp import Stamp
from lastmile.decision.gap_acceptance import arrival_on, clearance_time_s
from lastmile.decision.give_way_config import GiveWayConfig
from lastmile.hdmap.give_way_zones import Approach

APPROACH = Approach(
    lanelet_ids=(1,),
    centerline=Polyline(np.array([[0.0, 0.0], [100.0, 0.0]])),
    half_width_m=1.75,
    zone_start_m=80.0,
    zone_end_m=90.0,
)
CAR_LENGTH_M = 4.5


def _tracks(*rows: tuple[float, float, float, float, ObjectClass]) -> TrackedObjects:
    table = np.zeros((len(rows), len(TRACK_COLUMNS)))
    for k, (x, y, vx, vy, cls) in enumerate(rows):
        table[k, :8] = (x, y, vx, vy, CAR_LENGTH_M, 1.8, math.atan2(vy, vx), float(cls))
    return TrackedObjects(stamp=Stamp(0), ids=np.arange(len(rows), dtype=np.int64) + 1, table=table)


def test_a_moving_car_arrives_when_its_front_reaches_the_zone() -> None:
    (a,) = arrival_on(_tracks((50.0, 0.3, 10.0, 0.0, ObjectClass.CAR)), APPROACH, GiveWayConfig())
    assert a.track_id == 1
    assert a.time_s == pytest.approx((80.0 - (50.0 + CAR_LENGTH_M / 2)) / 10.0)
    assert a.leave_s == pytest.approx((90.0 - (50.0 - CAR_LENGTH_M / 2)) / 10.0)


def test_only_the_speed_along_the_lane_counts() -> None:
    # 30 degrees off the lane's direction: 10 m/s over ground, 8.66 m/s along it.
    v = 10.0
    (a,) = arrival_on(
        _tracks((50.0, 0.0, v * math.cos(math.pi / 6), v * math.sin(math.pi / 6), ObjectClass.CAR)),
        APPROACH,
        GiveWayConfig(),
    )
    assert a.time_s == pytest.approx((80.0 - 52.25) / (v * math.cos(math.pi / 6)))


def test_a_standing_car_short_of_the_zone_never_arrives_but_one_inside_it_blocks() -> None:
    cfg = GiveWayConfig()
    away = _tracks((60.0, 0.0, 0.3, 0.0, ObjectClass.CAR))  # radar jitter below moving_mps
    assert arrival_on(away, APPROACH, cfg) == []
    (inside,) = arrival_on(_tracks((84.0, 0.0, 0.0, 0.0, ObjectClass.CAR)), APPROACH, cfg)
    assert inside.time_s == 0.0
    assert inside.leave_s == math.inf
    # Its front just in the zone (centre 2 m short of it, half its length 2.25 m): in it.
    (touching,) = arrival_on(_tracks((78.0, 0.0, 0.0, 0.0, ObjectClass.CAR)), APPROACH, cfg)
    assert touching.time_s == 0.0


def test_road_users_past_the_zone_beside_it_oncoming_crossing_or_on_foot_do_not_count() -> None:
    tracks = _tracks(
        (93.0, 0.0, 8.0, 0.0, ObjectClass.CAR),  # its rear (90.75) has left the zone
        (50.0, 3.5, 8.0, 0.0, ObjectClass.CAR),  # the next lane
        (50.0, 0.0, -8.0, 0.0, ObjectClass.CAR),  # coming the other way
        (50.0, 0.0, 0.0, 8.0, ObjectClass.CAR),  # crossing the lane
        (70.0, 0.0, 1.4, 0.0, ObjectClass.PEDESTRIAN),  # the crosswalk and in-path rules' to judge
        (-10.0, 0.0, 8.0, 0.0, ObjectClass.CAR),  # upstream of the approach's start
    )
    assert arrival_on(tracks, APPROACH, GiveWayConfig()) == []


def test_cyclists_and_unclassified_movers_count() -> None:
    tracks = _tracks((40.0, 0.0, 5.0, 0.0, ObjectClass.CYCLIST), (30.0, -0.5, 8.0, 0.0, ObjectClass.UNKNOWN))
    assert sorted(a.track_id for a in arrival_on(tracks, APPROACH, GiveWayConfig())) == [1, 2]


def test_clearance_time_from_rest_within_the_acceleration_phase() -> None:
    # 8 m from rest at 0.8 m/s^2: sqrt(2 d / a) = sqrt(20) s, the top speed not reached.
    assert clearance_time_s(8.0, 0.0, 0.8, 5.0) == pytest.approx(math.sqrt(20.0))


def test_clearance_time_reaches_the_top_speed_and_holds_it() -> None:
    # 5 s to reach 4 m/s over 10 m, then 20 m at 4 m/s.
    assert clearance_time_s(30.0, 0.0, 0.8, 4.0) == pytest.approx(10.0)
    # Already at the top speed: distance over speed; a faster start is taken at the top speed (it
    # slows for the turn), never faster.
    assert clearance_time_s(12.0, 4.0, 0.8, 4.0) == pytest.approx(3.0)
    assert clearance_time_s(12.0, 6.0, 0.8, 4.0) == pytest.approx(3.0)
    assert clearance_time_s(0.0, 0.0, 0.8, 4.0) == 0.0
