"""Every decision state reaches EMERGENCY_STOP when the fail-safe orders it (WATonoBus Fig. 8)."""

from __future__ import annotations

import pytest

from lastmile.core.geometry import SE2
from lastmile.core.objects import empty_tracks
from lastmile.core.safety_messages import FailSafeLevel, MalfunctionKind, MalfunctionSignal
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourState
from lastmile.decision.behaviour_fsm import BehaviourStateMachine
from lastmile.decision.decision_config import DecisionInput
from lastmile.decision.mission import MissionManager
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.safety.failsafe import FailSafeArbiter


@pytest.mark.parametrize("state", list(BehaviourState), ids=[s.value for s in BehaviourState])
def test_safety_directive_brings_every_behaviour_state_to_emergency_stop(
    state: BehaviourState, straight_layers: SLayerDatabase
) -> None:
    fsm = BehaviourStateMachine(
        layers=straight_layers, geometry=VehicleGeometry(), mission=MissionManager(stop_order=("S1", "S2"))
    )
    fsm.state = state  # white-box: put the machine in each state directly
    signal = MalfunctionSignal(
        stamp=Stamp(1_000_000),
        source="localization",
        kind=MalfunctionKind.LOCALIZATION_INVALID,
        level=FailSafeLevel.EMERGENCY_STOP,
        reason="localization: no valid pose estimate",
    )
    directive = FailSafeArbiter().update(1_000_000, [signal], speed_mps=3.0)
    assert directive.emergency_stop
    # The wiring the README asks of the stack: an e-stop directive goes to request_emergency.
    fsm.request_emergency(1.0, "; ".join(directive.reasons))
    decision = fsm.step(
        DecisionInput(
            stamp=Stamp(1_000_000),
            map_from_base=SE2(150.0, 0.0, 0.0),
            speed_mps=3.0,
            route_s_m=150.0,
            route_d_m=0.0,
            tracks=empty_tracks(Stamp(0)),
            door_open=False,
            person_in_doorway=False,
            trajectory=None,
        )
    )
    assert decision.state == BehaviourState.EMERGENCY_STOP
    assert decision.speed_limit_mps == 0.0 and not decision.door_open
