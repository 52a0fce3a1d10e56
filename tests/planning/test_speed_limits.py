"""Snow Lion's speed constraints: curvature (eq. 1), pedestrian clearance (eq. 2), terminal stop."""

import math

import numpy as np
import pytest

from lastmile.core.curve_speed import curvature_speed_limit_mps
from lastmile.core.errors import ConfigError, MessageError
from lastmile.planning.speed_limits import (
    ClearanceSpeedConfig,
    clearance_speed_limit_mps,
    combined_speed_limit_mps,
    terminal_speed_limit_mps,
)


def test_curvature_limit_is_sqrt_a_lat_over_kappa():
    v = curvature_speed_limit_mps(np.array([0.0, 0.1, -0.25]), 1.0)
    assert v[0] == math.inf
    assert v[1] == pytest.approx(math.sqrt(10.0)) and v[2] == pytest.approx(2.0)


def test_clearance_limit_is_the_piecewise_lerp_of_eq_2():
    c = ClearanceSpeedConfig(
        delta_min_m=0.5, delta_mdn_m=1.5, delta_max_m=3.0, v_min_mps=1.0, v_mdn_mps=2.5, v_max_mps=5.0
    )
    v = clearance_speed_limit_mps(np.array([0.0, 0.5, 1.0, 1.5, 2.25, 3.0, 10.0, np.inf]), c)
    np.testing.assert_allclose(v, [1.0, 1.0, 1.75, 2.5, 3.75, 5.0, 5.0, 5.0])


def test_terminal_limit_stops_at_the_end():
    v = terminal_speed_limit_mps(np.array([0.0, 10.0, 12.0, 15.0]), 12.0, 1.0)
    np.testing.assert_allclose(v, [math.sqrt(24.0), 2.0, 0.0, 0.0])
    assert np.all(np.isinf(terminal_speed_limit_mps(np.array([0.0]), None, 1.0)))


def test_combined_is_the_lowest_of_all():
    s = np.array([0.0, 10.0, 20.0])
    v = combined_speed_limit_mps(
        s, np.array([0.0, 0.5, 0.0]), 5.0, 1.0, clearance_m=np.array([np.inf, np.inf, 0.2]), stop_s_m=None
    )
    np.testing.assert_allclose(v, [5.0, math.sqrt(2.0), 1.0])


def test_bad_thresholds_and_inputs_are_named():
    with pytest.raises(ConfigError, match="delta_min_m < delta_mdn_m"):
        ClearanceSpeedConfig(delta_mdn_m=0.2)
    with pytest.raises(MessageError, match="NaN"):
        clearance_speed_limit_mps(np.array([np.nan]))
