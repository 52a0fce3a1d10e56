"""Stop signs as virtual lines: a full stop of ``full_stop_s`` at the line, then on; never rolled through."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lastmile.core.geometry import SE2
from lastmile.core.objects import empty_tracks
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import StopReason
from lastmile.decision.behaviour_fsm import BehaviourStateMachine
from lastmile.decision.decision_config import DecisionInput
from lastmile.decision.mission import MissionManager
from lastmile.decision.stop_sign_rule import StopSignRule
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig
from lastmile.hdmap.layers import RouteStopLine, SLayerDatabase
from lastmile.hdmap.model import StopLine

LINE_S = 100.0
CONFIG = TrafficLightRuleConfig()
G = VehicleGeometry()
STOP_AT = LINE_S - CONFIG.stop_before_line_m


def _layers(straight_layers: SLayerDatabase, **ids: int | None) -> SLayerDatabase:
    line = StopLine(id=9, line=np.array([[LINE_S, -1.75], [LINE_S, 1.75]]), lanelet_id=1, **ids)
    rl = RouteStopLine(stop_line=line, s_m=LINE_S, all_way_stop_id=line.all_way_stop_id)
    return dataclasses.replace(straight_layers, stop_lines=(rl,))


def _ahead(s_m: float, front_s_m: float) -> float:
    return s_m - front_s_m


def test_the_shuttle_stands_the_full_stop_then_goes_and_is_released_past_the_line(
    straight_layers: SLayerDatabase,
) -> None:
    rule = StopSignRule(_layers(straight_layers, stop_sign_id=5))
    assert rule.step(0.0, LINE_S - CONFIG.approach_m - 1.0, 5.0, _ahead)[0] is None  # not yet approached
    assert rule.step(1.0, 50.0, 5.0, _ahead)[0] == pytest.approx(STOP_AT)
    # Standing at the point: held until full_stop_s has passed, then released.
    t0 = 10.0
    assert rule.step(t0, STOP_AT - 0.2, 0.0, _ahead)[0] == pytest.approx(STOP_AT)
    assert rule.step(t0 + CONFIG.full_stop_s - 0.1, STOP_AT - 0.2, 0.0, _ahead)[0] == pytest.approx(STOP_AT)
    stop, why = rule.step(t0 + CONFIG.full_stop_s, STOP_AT - 0.2, 0.0, _ahead)
    assert stop is None and "go" in why
    assert rule.step(t0 + 2.0, LINE_S - 0.2, 1.0, _ahead)[0] is None  # driving off over the line
    assert rule.step(t0 + 3.0, LINE_S + 5.0, 2.0, _ahead)[0] is None  # past it: nothing ahead


def test_creeping_or_standing_too_short_is_no_full_stop(straight_layers: SLayerDatabase) -> None:
    rule = StopSignRule(_layers(straight_layers, stop_sign_id=5))
    for k in range(40):  # 4 s creeping at 0.3 m/s near the line never counts as stopped
        assert rule.step(k * 0.1, STOP_AT - 2.0, 0.3, _ahead)[0] == pytest.approx(STOP_AT)
    # Standing 0.5 s, moving again, standing again: the clock starts afresh.
    rule.step(10.0, STOP_AT - 1.0, 0.0, _ahead)
    rule.step(10.5, STOP_AT - 1.0, 0.2, _ahead)
    rule.step(10.6, STOP_AT - 0.8, 0.0, _ahead)
    assert rule.step(11.2, STOP_AT - 0.8, 0.0, _ahead)[0] == pytest.approx(STOP_AT)
    assert rule.step(11.6, STOP_AT - 0.8, 0.0, _ahead)[0] is None


@pytest.mark.parametrize("other", [{"all_way_stop_id": 3}, {"signal_id": 4}, {}])
def test_only_a_two_way_stop_signs_line_is_taken(
    straight_layers: SLayerDatabase, other: dict[str, int]
) -> None:
    ids: dict[str, int | None] = {"stop_sign_id": 5 if other else None, **other}
    rule = StopSignRule(_layers(straight_layers, **ids))
    assert rule.lines == ()
    assert rule.step(0.0, 80.0, 5.0, _ahead) == (None, "")


def test_the_decision_stops_at_the_line_for_the_full_stop_then_drives_on(
    straight_layers: SLayerDatabase,
) -> None:
    fsm = BehaviourStateMachine(
        layers=_layers(straight_layers, stop_sign_id=5),
        geometry=G,
        mission=MissionManager(stop_order=("S1", "S2")),
    )
    rear_at = STOP_AT - 0.2 - G.front_from_rear_axle_m  # the front 0.2 m short of the stop point

    def step(t_s: float, rear_s_m: float, v: float) -> tuple[float | None, StopReason]:
        d = fsm.step(
            DecisionInput(
                stamp=Stamp(int(t_s * 1e6)),
                map_from_base=SE2(rear_s_m, 0.0, 0.0),
                speed_mps=v,
                route_s_m=rear_s_m,
                route_d_m=0.0,
                tracks=empty_tracks(Stamp(0)),
                door_open=False,
                person_in_doorway=False,
                trajectory=None,
            )
        )
        return d.stop_at_s_m, d.stop_reason

    assert step(0.0, 60.0, 5.0) == (pytest.approx(STOP_AT), StopReason.STOP_LINE)
    assert step(5.0, rear_at, 0.0) == (pytest.approx(STOP_AT), StopReason.STOP_LINE)
    assert step(5.0 + CONFIG.full_stop_s, rear_at, 0.0) == (None, StopReason.NONE)
