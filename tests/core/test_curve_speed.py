"""The curve speed planning's speed limits and decision's give-way clearance both read."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.curve_speed import curvature_speed_limit_mps
from lastmile.core.errors import ConfigError


def test_the_curve_speed_keeps_the_lateral_acceleration_and_is_unbounded_on_the_straight() -> None:
    v = curvature_speed_limit_mps(np.array([0.0, 0.1, -0.25]), 1.0)
    assert v[0] == math.inf and v[1] == pytest.approx(math.sqrt(10.0)) and v[2] == pytest.approx(2.0)
    assert float(np.min(curvature_speed_limit_mps(np.zeros(0), 1.0), initial=math.inf)) == math.inf


def test_a_lateral_acceleration_that_is_not_positive_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"expected a_lat > 0, got 0\.0"):
        curvature_speed_limit_mps(np.array([0.1]), 0.0)
