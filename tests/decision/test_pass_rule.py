"""The pass rule on the campus map: when a stationary obstacle blocking the lane is passed, and when not."""

from __future__ import annotations

import dataclasses
import functools

import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.vehicle import VehicleGeometry
from lastmile.decision.pass_config import PassConfig
from lastmile.decision.pass_rule import PassInput, PassPhase, PassRule
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop

GEOMETRY = VehicleGeometry()
FRONT_S_M = 380.0
"""On the bottom straight's broken centre line (route s 350-680 less the T's mouth)."""


@functools.lru_cache(maxsize=1)
def _layers() -> SLayerDatabase:
    hdmap = load_campus_map()
    return SLayerDatabase.build(hdmap, campus_shuttle_loop(hdmap), step_m=1.0, closed=True)


def _obstacle(
    track_id: int,
    ahead_m: float,
    d_m: float = 0.0,
    cls: ObjectClass = ObjectClass.CAR,
    v_s_mps: float = 0.0,
    front_s_m: float = FRONT_S_M,
) -> RouteObstacle:
    """A 4.5 x 1.8 m road user ``ahead_m`` (centre) in front of the shuttle's front."""
    s = front_s_m + ahead_m
    return RouteObstacle(
        track_id=track_id,
        cls=cls,
        x_m=0.0,
        y_m=0.0,
        s_m=s,
        ds_m=ahead_m,
        d_m=d_m,
        v_s_mps=v_s_mps,
        v_d_mps=0.0,
        length_m=4.5,
        width_m=1.8,
    )


def _rule(**changes: object) -> PassRule:
    return PassRule(_layers(), GEOMETRY, dataclasses.replace(PassConfig(), **changes), enabled=True)  # type: ignore[arg-type]


def _cycle(
    rule: PassRule,
    t_s: float,
    obstacles: list[RouteObstacle],
    front_s_m: float = FRONT_S_M,
    route_d_m: float = 0.3,
    speed_mps: float = 0.0,
) -> tuple[object, list[object]]:
    inp = PassInput(
        t_s=t_s,
        front_s_m=front_s_m,
        route_d_m=route_d_m,
        speed_mps=speed_mps,
        obstacles=obstacles,
        may_start=True,
    )
    return rule.step(inp)


def _settle(rule: PassRule, obstacles: list[RouteObstacle], until_s: float = 5.0, **kw: float) -> object:
    """Cycles at 10 Hz up to ``until_s``; the last request."""
    request = None
    for k in range(round(until_s * 10) + 1):
        request, _ = _cycle(rule, k / 10.0, obstacles, **kw)  # type: ignore[arg-type]
    return request


def test_a_parked_car_with_the_opposite_lane_clear_is_passed_once_it_has_stood_long_enough() -> None:
    rule = _rule()
    parked = [_obstacle(1, 22.25)]  # its rear 20 m ahead: the shuttle stands at the waiting point
    request, waits = _cycle(rule, 0.0, parked)
    assert request is None and waits  # it waits in its lane, 20 m behind
    assert rule.memory.why == "obstacle not standing long enough"
    request = _settle(rule, parked)
    assert request is not None and request.approved and request.track_id == 1  # type: ignore[attr-defined]
    assert request.left_d_m == pytest.approx(0.9) and request.max_d_m == pytest.approx(1.75 + 3.5)  # type: ignore[attr-defined]
    assert rule.phase is PassPhase.PASSING


def test_an_oncoming_car_within_the_manoeuvres_reach_makes_it_wait_one_beyond_does_not() -> None:
    near = [_obstacle(1, 22.25), _obstacle(2, 80.0, d_m=3.5, v_s_mps=-6.0)]
    rule = _rule()
    request = _settle(rule, near)
    assert request is not None and not request.approved  # type: ignore[attr-defined]
    assert "oncoming track 2" in rule.memory.why
    far = [_obstacle(1, 22.25), _obstacle(2, 180.0, d_m=3.5, v_s_mps=-6.0)]
    rule = _rule()
    request = _settle(rule, far)
    assert request is not None and request.approved  # type: ignore[attr-defined]


def test_a_begun_pass_is_called_off_when_a_car_appears_but_not_once_committed() -> None:
    parked = [_obstacle(1, 22.25)]
    oncoming = [*parked, _obstacle(2, 70.0, d_m=3.5, v_s_mps=-6.0)]
    rule = _rule()
    assert _settle(rule, parked).approved  # type: ignore[attr-defined]
    # Still in its lane (0.1 m out), standing: the pass is called off, the shuttle waits again.
    request, waits = _cycle(rule, 6.0, oncoming, route_d_m=0.1, speed_mps=0.0)
    assert request is not None and not request.approved and waits  # type: ignore[attr-defined]
    rule = _rule()
    _settle(rule, parked)
    request, _ = _cycle(rule, 5.6, parked, route_d_m=0.5)  # out of the lane: committed
    assert request is not None and request.committed  # type: ignore[attr-defined]
    request, waits = _cycle(rule, 5.7, oncoming, route_d_m=0.6)
    assert request is not None and request.approved and request.committed and not waits  # type: ignore[attr-defined]


def test_no_pass_across_a_solid_line_at_a_stop_line_in_a_queue_or_of_a_pedestrian() -> None:
    # Route s 250: the bottom straight west of the T, whose centre line is solid (crosswalk C1 on it).
    rule = _rule()
    assert _settle(rule, [_obstacle(1, 22.25, front_s_m=250.0)], front_s_m=250.0) is None
    assert "not passable (line_thin:solid)" in rule.memory.why
    # A car standing 1 m before the signal's stop line (route s 840.6) waits for the light.
    rule = _rule()
    front = 840.6 - 1.0 - 2.25 - 22.25
    assert _settle(rule, [_obstacle(1, 22.25, front_s_m=front)], front_s_m=front) is None
    assert rule.memory.why == "obstacle waits at a stop line, crosswalk or junction"
    # A car standing behind another: a queue.
    rule = _rule()
    assert _settle(rule, [_obstacle(1, 22.25), _obstacle(3, 32.0)]) is None
    assert rule.memory.why == "obstacle is in a queue"
    rule = _rule()
    assert _settle(rule, [_obstacle(1, 22.25, cls=ObjectClass.PEDESTRIAN)]) is None
    assert rule.phase is PassPhase.NONE


def test_an_obstacle_leaving_room_in_the_lane_is_left_to_the_nudge_and_a_close_one_is_not_begun() -> None:
    rule = _rule()
    kerbside = dataclasses.replace(_obstacle(1, 22.25, d_m=-1.6), width_m=0.5)  # a bin at the kerb
    assert _settle(rule, [kerbside]) is None and rule.phase is PassPhase.NONE
    rule = _rule()
    assert _settle(rule, [_obstacle(1, 8.0)]) is None  # its rear 5.75 m ahead: no room to steer out
    assert rule.memory.why == "too close behind the obstacle to steer out"


def test_the_view_past_the_obstacle_limits_the_sight_distance() -> None:
    rule = _rule()
    inp = PassInput(t_s=0.0, front_s_m=FRONT_S_M, route_d_m=0.3, speed_mps=0.0, obstacles=[], may_start=True)
    behind_15 = rule.sight_m(inp, _obstacle(1, 17.25))
    # The ray over the car's near left corner (0.9 m) meets the oncoming lane's centre (3.5 m).
    assert behind_15 == pytest.approx(15.0 * (3.5 - 0.3) / (0.9 - 0.3))
    centred = dataclasses.replace(inp, route_d_m=0.0)
    assert rule.sight_m(centred, _obstacle(1, 17.25)) == pytest.approx(15.0 * 3.5 / 0.9)
    assert rule.sight_m(dataclasses.replace(inp, route_d_m=1.0), _obstacle(1, 17.25)) == 90.0


def test_disabled_it_orders_nothing_and_bad_parameters_are_refused() -> None:
    rule = PassRule(_layers(), GEOMETRY, PassConfig(), enabled=False)
    assert _settle(rule, [_obstacle(1, 22.25)]) is None
    with pytest.raises(ConfigError, match=r"passing\.wait_gap_m: expected a positive number"):
        PassConfig(wait_gap_m=0.0)


def test_a_moving_lead_car_is_followed_not_waited_for() -> None:
    rule = _rule()
    lead = [_obstacle(1, 22.25, v_s_mps=5.0)]
    request, waits = _cycle(rule, 0.0, lead)
    assert request is None and waits == [] and rule.phase is PassPhase.NONE


def test_tracks_splitting_one_parked_car_are_one_obstacle_not_a_queue() -> None:
    """Raw perception tracks a parked car as several LiDAR clusters side by side along it."""
    pieces = [
        dataclasses.replace(_obstacle(k, ahead, d_m=d), length_m=1.6, width_m=w)
        for k, (ahead, d, w) in enumerate(((20.8, 0.0, 0.7), (22.2, 0.05, 1.3), (23.7, -0.05, 0.2)), start=1)
    ]
    rule = _rule()
    request = _settle(rule, pieces)
    assert request is not None and request.approved  # type: ignore[attr-defined]
    assert request.start_s_m == pytest.approx(FRONT_S_M + 20.0)  # type: ignore[attr-defined]
    assert request.end_s_m == pytest.approx(FRONT_S_M + 24.5)  # type: ignore[attr-defined]
    assert request.left_d_m == pytest.approx(0.05 + 0.65)  # type: ignore[attr-defined]
