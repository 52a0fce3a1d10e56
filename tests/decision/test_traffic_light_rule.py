"""Traffic-light rule: red stops, yellow only when comfortable, flashing red stops first, unknown is red."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import LightState, TrafficLightStates
from lastmile.decision.traffic_light_rule import TrafficLightRule, TrafficLightRuleConfig
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop


@functools.cache
def _layers() -> SLayerDatabase:
    hdmap = load_campus_map()
    return SLayerDatabase.build(hdmap, campus_shuttle_loop(hdmap), step_m=1.0, closed=True)


def _line_s() -> float:
    (rl,) = _layers().signal_stop_lines
    return rl.s_m


def _ahead(s_m: float, front_s: float) -> float:
    return s_m - front_s


def _states(state: LightState, flashing: bool = False, heads: int = 2) -> TrafficLightStates:
    """Tracked states for the first ``heads`` heads of the shuttle's signal."""
    (rl,) = _layers().signal_stop_lines
    sig = _layers().hdmap.signal(rl.stop_line.signal_id or -1)
    ids = tuple(h.light_id for h in sig.heads[:heads])
    n = len(ids)
    return TrafficLightStates(
        stamp=Stamp(0), light_ids=ids, track_ids=np.arange(n), states=np.full(n, int(state)),
        probs=np.tile(np.eye(4)[int(state)], (n, 1)), confidence=np.ones(n), flashing=np.full(n, flashing),
        frames_since_seen=np.zeros(n, dtype=np.int64), stop_line_ids=np.full(n, rl.stop_line.id),
        stop_xy_m=np.zeros((n, 2)),
    )  # fmt: skip


def test_red_stops_at_the_line_and_green_goes() -> None:
    rule = TrafficLightRule(_layers())
    stop, why = rule.step(0.0, _line_s() - 30.0, 5.5, _states(LightState.RED), _ahead)
    assert stop == pytest.approx(_line_s() - 0.5) and "red" in why
    assert rule.step(0.1, _line_s() - 29.0, 5.5, _states(LightState.GREEN), _ahead)[0] is None


def test_yellow_stops_when_comfortable_and_goes_when_too_close_and_keeps_its_choice() -> None:
    # 5.5 m/s: stopping within 20 m needs 0.76 m/s^2 (comfortable); within 5 m, 3.3 m/s^2 (not).
    far = TrafficLightRule(_layers())
    assert far.step(0.0, _line_s() - 20.0, 5.5, _states(LightState.YELLOW), _ahead)[0] is not None
    # Braking, it gets close at a speed whose v^2/2d now exceeds the comfort bound: still stops.
    assert far.step(1.0, _line_s() - 3.0, 4.0, _states(LightState.YELLOW), _ahead)[0] is not None
    near = TrafficLightRule(_layers())
    stop, why = near.step(0.0, _line_s() - 5.0, 5.5, _states(LightState.YELLOW), _ahead)
    assert stop is None and "go" in why
    # Turning red while it crosses: committed, no late hard stop.
    assert near.step(0.5, _line_s() - 2.5, 5.5, _states(LightState.RED), _ahead)[0] is None


def test_flashing_red_is_a_stop_sign() -> None:
    rule = TrafficLightRule(_layers(), TrafficLightRuleConfig(full_stop_s=1.0))
    fr = _states(LightState.RED, flashing=True)
    assert rule.step(0.0, _line_s() - 20.0, 5.0, fr, _ahead)[0] is not None
    assert rule.step(5.0, _line_s() - 1.0, 0.0, fr, _ahead)[0] is not None  # just stopped
    assert rule.step(5.5, _line_s() - 1.0, 0.0, fr, _ahead)[0] is not None  # not long enough
    stop, why = rule.step(6.1, _line_s() - 1.0, 0.0, fr, _ahead)
    assert stop is None and "go" in why
    assert rule.step(6.5, _line_s() - 0.8, 0.5, fr, _ahead)[0] is None  # and it stays a go


def test_flashing_yellow_goes() -> None:
    rule = TrafficLightRule(_layers())
    assert rule.step(0.0, _line_s() - 10.0, 5.0, _states(LightState.YELLOW, flashing=True), _ahead)[0] is None


def test_a_signal_nobody_sees_is_red_near_the_line_only() -> None:
    rule = TrafficLightRule(_layers(), TrafficLightRuleConfig(unknown_as_red_m=40.0))
    assert rule.step(0.0, _line_s() - 50.0, 5.5, None, _ahead)[0] is None
    stop, why = rule.step(0.0, _line_s() - 35.0, 5.5, None, _ahead)
    assert stop is not None and "unknown" in why
    dark = _states(LightState.OFF)
    assert rule.step(0.1, _line_s() - 34.0, 5.5, dark, _ahead)[0] is not None


def test_heads_that_disagree_are_read_as_the_most_restrictive() -> None:
    rule = TrafficLightRule(_layers())
    mixed = _states(LightState.GREEN)
    states = mixed.states.copy()
    states[1] = int(LightState.RED)
    mixed = dataclasses.replace(mixed, states=states)
    (rl,) = _layers().signal_stop_lines
    assert rule.signal_state(rl.stop_line.id, mixed) == "red"


def test_bad_rule_config_raises() -> None:
    with pytest.raises(ConfigError, match="unknown_as_red_m"):
        TrafficLightRuleConfig(unknown_as_red_m=80.0, approach_m=60.0)
