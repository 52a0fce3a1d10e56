"""Module timing keeps each module's warm-up (its first call) apart from its steady-state latency."""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

from lastmile.stack import profiler as profiler_module
from lastmile.stack.profiler import HISTOGRAM_EDGES_MS, ModuleProfiler


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
    # Sleeping is wall time, not CPU time: the CPU factor of a run leaves out only what the warm-up
    # computed (on a loaded machine its wall time also holds the other processes' turns).
    assert 0.0 <= row["warmup_cpu_ms"] < 100.0


def test_a_module_called_once_has_only_a_warm_up() -> None:
    profiler = ModuleProfiler()
    with profiler.measure("planning"):
        pass
    row = profiler.summary()["planning"]
    assert row["calls"] == 0 and row["p50_ms"] is None and row["warmup_ms"] is not None


def test_calls_over_the_cycle_budget_are_counted_and_binned(monkeypatch: pytest.MonkeyPatch) -> None:
    # The profiler's clock is stepped by hand: a sleep of 0.5 ms can take over the 5 ms budget on a
    # loaded machine, and this test is about the counting, not about the machine.
    now = [0.0]
    clock = SimpleNamespace(perf_counter=lambda: now[0], thread_time=lambda: now[0])
    monkeypatch.setattr(profiler_module, "time", clock)
    profiler = ModuleProfiler({"planning": 5.0})
    for k in range(6):
        with profiler.measure("planning"):
            now[0] += 0.3 if k == 0 else 0.012 if k in (2, 4) else 0.0005
    row = profiler.summary()["planning"]
    assert row["budget_ms"] == 5.0 and row["over_budget"] == 2  # the warm-up is not an overrun
    assert sum(row["histogram"]) == row["calls"] == 5
    assert len(row["histogram"]) == len(HISTOGRAM_EDGES_MS) - 1
    assert row["cpu_p50_ms"] == pytest.approx(0.5)  # the thread's CPU clock, stepped alike here


def test_a_call_during_which_numba_compiles_is_warm_up_wherever_it_falls() -> None:
    from numba import njit

    @njit(cache=False)
    def fresh_kernel(x: float) -> float:  # never compiled before: its first call compiles
        return x * 2.0 + 1.0

    profiler = ModuleProfiler()
    for k in range(6):
        with profiler.measure("perception"):
            if k == 3:  # the first complete frame reaches the kernel on the fourth call
                fresh_kernel(1.0)
    row = profiler.summary()["perception"]
    assert row["warmup_calls"] == 2 and row["calls"] == 4
    assert row["max_ms"] is not None and row["warmup_ms"] > 10 * row["max_ms"]
