"""The simulated radar's masking: a nearer object hides the bearings its outline spans, not more."""

from __future__ import annotations

import math

import pytest

from lastmile.sim.sensors import _bearing_span


def test_a_car_seen_from_behind_spans_its_width_not_its_length() -> None:
    mid, half = _bearing_span(15.0 + 2.25, 0.0, 0.0, 4.5, 1.8)  # rear 15 m ahead, aligned
    assert mid == pytest.approx(0.0)
    assert half == pytest.approx(math.atan2(0.9, 15.0))  # its near corners bound the span: 3.4 deg
    assert math.degrees(half) < 3.5  # its length would have given atan(2.25 / 15) = 8.5 deg


def test_a_car_seen_side_on_spans_its_length() -> None:
    mid, half = _bearing_span(0.0, 20.0, 0.0, 4.5, 1.8)  # 20 m to the left, broadside
    assert mid == pytest.approx(math.pi / 2.0, abs=1e-9)
    assert half == pytest.approx(math.atan2(2.25, 20.0 - 0.9))
