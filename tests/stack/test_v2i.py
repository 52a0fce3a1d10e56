"""Crossing anticipation: a crossing the infrastructure reports occupied asks for a comfortable stop
before it; clear, stale, too close or out-of-order reports do not."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.sensor_frames import CrossingPresenceFrame
from lastmile.core.stamp import Stamp
from lastmile.hdmap.layers import RouteCrosswalk
from lastmile.hdmap.model import Crosswalk
from lastmile.stack.v2i import AnticipationConfig, CrossingAnticipation

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _anticipation() -> CrossingAnticipation:
    crossings = (
        RouteCrosswalk(
            crosswalk=Crosswalk(id=3, polygon=SQUARE, width_m=4.0), s_start_m=100.0, s_end_m=104.0
        ),
        RouteCrosswalk(crosswalk=Crosswalk(id=5, polygon=SQUARE, width_m=4.0), s_start_m=5.0, s_end_m=9.0),
    )
    return CrossingAnticipation(crossings, route_length_m=400.0, closed=True)


def _report(cw: int, present: bool, captured_s: float) -> CrossingPresenceFrame:
    return CrossingPresenceFrame(
        stamp=Stamp(int(captured_s * 1e6) + 100_000),
        node_id=f"cam-{cw}",
        crosswalk_id=cw,
        pedestrians_present=present,
        captured=Stamp(int(captured_s * 1e6)),
    )


def test_reported_pedestrians_ask_for_a_stop_before_the_crosswalk() -> None:
    a = _anticipation()
    assert a.stop_point(Stamp(1_000_000), front_s_m=60.0, speed_mps=5.0) is None  # no report yet
    a.on_frame(_report(3, True, 0.9))
    assert a.stop_point(Stamp(1_000_000), front_s_m=60.0, speed_mps=5.0) == pytest.approx(99.0)
    a.on_frame(_report(3, False, 1.1))  # the crossing is clear again: no stop
    assert a.stop_point(Stamp(1_200_000), front_s_m=60.0, speed_mps=5.0) is None


def test_stale_too_close_out_of_order_and_wrapped_reports() -> None:
    a = _anticipation()
    a.on_frame(_report(3, True, 0.0))
    assert a.stop_point(Stamp(3_000_000), front_s_m=60.0, speed_mps=5.0) is None  # 3 s old: stale
    a.on_frame(_report(3, True, 2.9))
    a.on_frame(_report(3, False, 2.0))  # older than the one kept: ignored
    assert a.stop_point(Stamp(3_000_000), front_s_m=60.0, speed_mps=5.0) == pytest.approx(99.0)
    # 9 m before the line at 5 m/s needs 12.5 m at 1 m/s^2: left to the onboard sensors.
    assert a.stop_point(Stamp(3_000_000), front_s_m=90.0, speed_mps=5.0) is None
    # Across the loop's seam: crossing 5 at s 5..9 is 14 m ahead of s 390.
    a.on_frame(_report(5, True, 2.9))
    assert a.stop_point(Stamp(3_000_000), front_s_m=390.0, speed_mps=2.0) == pytest.approx(4.0)


def test_a_nearer_stop_of_the_decision_keeps_binding() -> None:
    a = _anticipation()
    assert a.nearer(99.0, None, 60.0)
    assert not a.nearer(99.0, 80.0, 60.0)
    assert not a.nearer(99.0, 59.5, 60.0)  # a stop point just behind the front (standing) binds
    assert a.nearer(4.0, 50.0, 390.0)  # across the seam


def test_bad_frames_and_configs_are_refused() -> None:
    with pytest.raises(MessageError, match="crosswalk_id"):
        _report(-1, True, 0.0).validate()
    with pytest.raises(ConfigError, match="max_age_s"):
        AnticipationConfig(max_age_s=0.0)
