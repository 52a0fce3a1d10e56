"""Module timing keeps each module's warm-up (its first call) apart from its steady-state latency."""

from __future__ import annotations

import time

import pytest

from lastmile.stack.profiler import ModuleProfiler


def test_the_first_call_is_reported_as_warm_up_and_kept_out_of_the_percentiles() -> None:
    profiler = ModuleProfiler()
    for k in range(5):
        with profiler.measure("perception"):
            time.sleep(0.2 if k == 0 else 0.001)  # a first frame that compiles, then steady frames
    row = profiler.summary()["perception"]
    assert row["calls"] == 4
    assert row["warmup_ms"] is not None and row["warmup_ms"] >= 200.0
    assert row["max_ms"] is not None and row["max_ms"] < 100.0
    assert profiler.warmup_s() == pytest.approx(row["warmup_ms"] / 1e3)


def test_a_module_called_once_has_only_a_warm_up() -> None:
    profiler = ModuleProfiler()
    with profiler.measure("planning"):
        pass
    row = profiler.summary()["planning"]
    assert row["calls"] == 0 and row["p50_ms"] is None and row["warmup_ms"] is not None
