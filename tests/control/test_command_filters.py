"""Controller output stages: low-pass filter and rate limiter (properties)."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lastmile.control.command_filters import LowPassFilter, RateLimiter, SteeringOutput
from lastmile.core.errors import ConfigError

finite = st.floats(-10.0, 10.0, allow_nan=False)


@given(st.lists(finite, min_size=2, max_size=50), st.floats(0.01, 1.0), st.floats(0.001, 0.1))
def test_rate_limiter_never_moves_faster_than_its_rates(inputs, rate, dt):
    r = RateLimiter(rate, 2.0 * rate)
    last = r.step(dt, inputs[0])
    for u in inputs[1:]:
        y = r.step(dt, u)
        assert -2.0 * rate * dt - 1e-12 <= y - last <= rate * dt + 1e-12
        # It moves toward the input, never past it.
        assert min(last, u) - 1e-12 <= y <= max(last, u) + 1e-12
        last = y


@given(finite, finite, st.floats(0.01, 2.0), st.floats(0.001, 0.1))
def test_lowpass_step_response_is_the_exact_first_order_one(u0, u1, tau, dt):
    f = LowPassFilter(tau)
    f.step(dt, u0)
    y = u0
    for k in range(1, 20):
        y = f.step(dt, u1)
        expected = u1 + (u0 - u1) * math.exp(-k * dt / tau)
        assert y == pytest.approx(expected, abs=1e-9)


def test_steering_output_clamps_then_limits_rate():
    out = SteeringOutput(0.5, 1.0, 0.0)
    assert out.step(0.02, 0.3) == 0.3  # first command passes (no history)
    assert out.step(0.02, 2.0) == pytest.approx(0.32)
    out.reset()
    assert out.step(0.02, 2.0) == 0.5


def test_bad_filter_parameters_are_named():
    with pytest.raises(ConfigError, match="tau_s"):
        LowPassFilter(-1.0)
    with pytest.raises(ConfigError, match="rise_per_s"):
        RateLimiter(0.0)
