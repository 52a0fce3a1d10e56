"""The traffic-light rule's per-verdict steps, each called on its own with a line being approached."""

from __future__ import annotations

import pytest

from lastmile.decision import traffic_light_rule as tlr
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig

C = TrafficLightRuleConfig()


def _line(gap_m: float, speed_mps: float, t_s: float = 0.0) -> tlr._LineApproach:
    dist = gap_m + C.stop_before_line_m
    return tlr._LineApproach(t_s=t_s, speed_mps=speed_mps, dist_m=dist, stop_s_m=100.0, gap_m=gap_m)


def test_every_verdict_has_a_rule() -> None:
    verdicts = {tlr.RED, tlr.YELLOW, tlr.GREEN, tlr.FLASHING_RED, tlr.FLASHING_YELLOW, tlr.UNKNOWN}
    assert set(tlr._VERDICT_RULES) == verdicts


def test_go_verdicts_forget_a_yellow_choice() -> None:
    st = tlr._Approach(yellow_choice="stop")
    assert tlr._VERDICT_RULES[tlr.GREEN](C, st, _line(10.0, 5.0)) == (None, "signal green: go")
    assert st.yellow_choice == ""


def test_yellow_stops_only_when_comfortable_and_keeps_its_choice() -> None:
    st = tlr._Approach()
    # 5 m/s, 12 m: the ramped-in comfortable stop needs 10.3 m: stop, and keep stopping once closer.
    assert tlr._yellow(C, st, _line(12.0, 5.0))[0] == 100.0
    assert tlr._yellow(C, st, _line(2.0, 5.0))[0] == 100.0
    st = tlr._Approach()
    # 5 m/s, 4 m: 3.1 m/s^2: go, and a red after it does not become a hard stop.
    assert tlr._yellow(C, st, _line(4.0, 5.0))[0] is None
    assert tlr._red(C, st, _line(3.0, 5.0)) == (None, "signal turned red after the yellow go: committed")
    # Slow enough to stop comfortably after all: the red is obeyed.
    assert tlr._red(C, st, _line(3.0, 2.0))[0] == 100.0


def test_yellow_counts_the_metres_the_braking_ramp_covers() -> None:
    # Seed 3 in snow: yellow seen 8.5 m before the stop point at 5.5 m/s. v^2 / 2d = 1.8 m/s^2 looks
    # comfortable, but with the ramp-in it needs ~3 m/s^2: go on (the yellow lasts 3-6 s, 1.5 s to the line).
    assert C.comfort_decel_mps2 >= 5.5**2 / (2.0 * 8.5)
    assert tlr._yellow(C, tlr._Approach(), _line(8.5, 5.5))[0] is None
    assert tlr._yellow(C, tlr._Approach(), _line(13.0, 5.5))[0] == 100.0


def test_comfortable_stop_distance_matches_a_jerk_limited_stop() -> None:
    # Integrate the braking the model describes (reaction at the present acceleration, then the
    # acceleration ramped down at the jerk to the comfort deceleration, held) at 1 ms.
    for v0, a0 in ((0.8, 0.0), (2.0, 0.0), (4.0, 0.0), (5.5, 0.0), (0.23, 1.0), (3.0, 0.6), (2.0, -0.5)):
        v, a, s, t, dt = v0, max(a0, 0.0), 0.0, 0.0, 1e-3
        while v > 0.0:
            if t >= C.reaction_s:
                a = max(a - C.brake_jerk_mps3 * dt, -C.comfort_decel_mps2)
            s += v * dt + 0.5 * a * dt * dt
            v += a * dt
            t += dt
        assert tlr.comfortable_stop_m(v0, C, a0) == pytest.approx(s, abs=0.02), (v0, a0)
    # Merging off at 0.52 m/s and 0.97 m/s^2 (snow seed 2) a stop takes 1.28 m, not 0.34.
    assert tlr.comfortable_stop_m(0.52, C) < 0.35 < 1.25 < tlr.comfortable_stop_m(0.52, C, 0.97)


def test_unknown_is_red_only_near_the_line() -> None:
    assert tlr._unknown(C, tlr._Approach(), _line(C.unknown_as_red_m + 1.0, 5.0)) == (None, "")
    assert tlr._unknown(C, tlr._Approach(), _line(C.unknown_as_red_m - 5.0, 5.0))[0] == 100.0


def test_flashing_red_stands_the_full_stop_then_goes() -> None:
    st = tlr._Approach()
    assert tlr._flashing_red(C, st, _line(10.0, 3.0))[0] == 100.0  # still approaching
    assert tlr._flashing_red(C, st, _line(1.0, 0.0, t_s=5.0))[0] == 100.0  # standing at the line
    assert st.stopped_since_s == 5.0
    assert tlr._flashing_red(C, st, _line(1.0, 0.0, t_s=5.0 + C.full_stop_s))[0] is None
    assert st.cleared
    assert tlr._flashing_red(C, st, _line(-0.2, 2.0, t_s=7.0))[0] is None
