"""The indicator lights in the loop: a passenger's drop-off on the campus, radar tracking.

The shuttle starts on the bottom straight at route s 360 (heading +x, the kerb on its right, -y); a
rider presses the drop-off button at t = 2 s. The command the vehicle receives (the safety's verdict)
must show right before the body moves towards the kerb and left before it moves out of the bay.
"""

from __future__ import annotations

import pytest

from lastmile.core.vehicle_messages import BehaviourState, TurnSignal
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import DropOffRequest, Scenario
from tests.closed_loop.harness import Step, steps

pytestmark = pytest.mark.closed_loop
NO_RIDERS = PassengerConfig(arrivals_per_stop_per_min=0.0, initial_waiting={})
MOVE_M = 0.1
"""A sideways move of the rear axle this large (truth) counts as the body having begun to move."""


def _scenario() -> Scenario:
    return Scenario(
        name="turn_signals",
        minutes=0.75,
        passengers=NO_RIDERS,
        start_route_s_m=360.0,
        drop_off_requests=(DropOffRequest(t_s=2.0),),
    )


def _merged(step: Step, seen: set[BehaviourState]) -> bool:
    d = step.out.decision
    if d is not None:
        seen.add(d.state)
    return BehaviourState.MERGING in seen and d is not None and d.state is BehaviourState.NORMAL_DRIVING


def test_right_before_moving_to_the_kerb_left_before_moving_out() -> None:
    seen: set[BehaviourState] = set()
    lane_y = None
    bay_y = None
    moved_right_signal = moved_left_signal = None
    signals: list[tuple[float, TurnSignal]] = []
    for step in steps(_scenario(), until=lambda s: _merged(s, seen)):
        command = step.verdict.command
        signal = command.turn_signal if command is not None else TurnSignal.OFF
        if not signals or signals[-1][1] is not signal:
            signals.append((step.t_s, signal))
        ego = step.sim.world.ego.state
        if lane_y is None and step.t_s >= 1.9:
            lane_y = ego.y_m  # in the lane, just before the button is pressed
        if lane_y is not None and moved_right_signal is None and ego.y_m < lane_y - MOVE_M:
            moved_right_signal = signal
        if step.out.decision is not None and step.out.decision.state is BehaviourState.ONBOARDING:
            bay_y = ego.y_m
        if bay_y is not None and moved_left_signal is None and ego.y_m > bay_y + MOVE_M:
            moved_left_signal = signal
    assert BehaviourState.MERGING in seen, f"never merged: {signals}"
    assert moved_right_signal is TurnSignal.RIGHT, signals
    assert moved_left_signal is TurnSignal.LEFT, signals
    on = [s for _, s in signals]
    assert TurnSignal.HAZARD not in on, signals
    # Right, then off while standing in the bay, then left: one of each, in that order.
    assert on[on.index(TurnSignal.RIGHT) :] == [
        TurnSignal.RIGHT,
        TurnSignal.OFF,
        TurnSignal.LEFT,
        TurnSignal.OFF,
    ]
