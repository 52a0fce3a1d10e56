"""Short closed-loop runs at the signalised crossing (C2): red then green, flashing red, a dark signal.

The shuttle starts 100 m before the stop line; the stack sees the signal only through the simulated
camera light detector, its tracker and the decision rule. The judge reads the true signal state.
"""

from __future__ import annotations

import pytest

from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import Scenario
from lastmile.sim.traffic_signals import SignalConfig
from tests.closed_loop.harness import steps

pytestmark = pytest.mark.closed_loop
NO_RIDERS = PassengerConfig(arrivals_per_stop_per_min=0.0, initial_waiting={})
START_S_M = 740.0  # route s of the rear axle; the signal's stop line is at route s 840.6


def _run(signals: SignalConfig, minutes: float) -> tuple[list[float], list[tuple[float, str, dict]], str]:
    """(times the shuttle stood with its front 0-4 m before the line, the judge's events, last reason)."""
    scenario = Scenario(
        name="traffic_light", minutes=minutes, passengers=NO_RIDERS, start_route_s_m=START_S_M,
        traffic_signals=signals,
    )  # fmt: skip
    stood: list[float] = []
    last = None
    for step in steps(scenario):
        last = step
        w = step.sim.world
        for line in w.stop_lines:
            along = w.ego_stop_line_distance(line)
            if along is not None and 0.0 <= along <= 4.0 and w.ego.state.speed_mps < 0.05:
                stood.append(step.t_s)
    assert last is not None and last.out.decision is not None
    return stood, last.sim.judge.events, last.out.decision.reason


def test_stops_on_red_and_goes_on_green() -> None:
    # Red from t = 0 to 30 s (the cycle starts 33.5 s in, at the end of its yellow), then green.
    stood, events, _ = _run(SignalConfig(green_s=30.0, yellow_s=3.5, red_s=30.0, offset_s=33.5), minutes=0.65)
    assert stood and min(stood) < 28.0, "the shuttle never stood at the line while it was red"
    entries = [e for e in events if e[1] == "signal_entry"]
    assert len(entries) == 1 and entries[0][2]["shown"] == "green" and entries[0][0] >= 30.0
    assert entries[0][0] < 35.0, "the shuttle did not go within 5 s of green"
    assert not [e for e in events if e[1] in ("rule_violation", "collision", "takeover")]


def test_flashing_red_is_a_stop_sign_stop_then_proceed() -> None:
    stood, events, _ = _run(SignalConfig(mode="flashing_red"), minutes=0.55)
    assert stood, "the shuttle did not stop at the flashing red"
    entries = [e for e in events if e[1] == "signal_entry"]
    assert len(entries) == 1 and entries[0][2]["stopped_before"], entries
    assert not [e for e in events if e[1] in ("rule_violation", "collision", "takeover")]


def test_flashing_yellow_is_passed_without_stopping() -> None:
    stood, events, _ = _run(SignalConfig(mode="flashing_yellow"), minutes=0.45)
    assert not stood
    entries = [e for e in events if e[1] == "signal_entry"]
    assert len(entries) == 1 and not entries[0][2]["stopped_before"]


def test_a_dark_signal_is_treated_as_red() -> None:
    stood, events, reason = _run(SignalConfig(mode="dark"), minutes=0.6)
    assert stood and max(stood) > 35.0  # still standing at the end of the run
    assert not [e for e in events if e[1] == "signal_entry"], "drove through a signal it could not see"
    assert "unknown" in reason
