"""Per-module compute time: measured for reports only, never used for decisions (the loop owns time)."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Mapping
from typing import Any

import numpy as np
from numba.core import event as numba_event

from lastmile.core import vehicle_messages

HISTOGRAM_EDGES_MS = vehicle_messages.LATENCY_HISTOGRAM_EDGES_MS


class _CompileClock(numba_event.Listener):
    """Seconds Numba has spent compiling or loading compiled kernels from its cache in this process.

    Both happen while Numba holds its compiler lock (``numba:compiler_lock`` events, which enclose the
    ``numba:compile`` ones); nested events count once.
    """

    def __init__(self) -> None:
        self.total_s = 0.0
        self._depth = 0
        self._t0 = 0.0

    def on_start(self, event: Any) -> None:
        if self._depth == 0:
            self._t0 = time.perf_counter()
        self._depth += 1

    def on_end(self, event: Any) -> None:
        self._depth -= 1
        if self._depth == 0:
            self.total_s += time.perf_counter() - self._t0


COMPILE_CLOCK = _CompileClock()
numba_event.register("numba:compiler_lock", COMPILE_CLOCK)


class ModuleProfiler:
    """Collects the wall time of each module call; ``summary`` gives p50/p95/max in ms, warm-up apart.

    Warm-up is a module's first call (first allocations, caches filling) and every call during which
    Numba compiled or loaded a kernel from its cache (a kernel compiles on the first frame that reaches
    it: up to tens of seconds, against milliseconds in steady state). Warm-up calls are reported as
    ``warmup_ms`` and ``warmup_calls`` and kept out of the percentiles, ``calls`` and the overrun count,
    so that neither a latency nor a real-time factor mixes the two.
    """

    def __init__(self, budgets_ms: Mapping[str, float] | None = None) -> None:
        self._samples: dict[str, list[float]] = defaultdict(list)
        self._cpu_samples: dict[str, list[float]] = defaultdict(list)
        self._warmup: dict[str, list[bool]] = defaultdict(list)
        self.budgets_ms = dict(budgets_ms or {})
        """Each module's cycle budget (its period): calls over it are counted as overruns."""

    def measure(self, module: str) -> _Measurement:
        """A context that records the wall and CPU time of its body as one call of ``module``."""
        return _Measurement(self, module)

    def _record(self, module: str, wall_s: float, cpu_s: float, compiled: bool) -> None:
        self._samples[module].append(wall_s)
        # This thread's CPU time too: on a shared machine wall time counts the other processes' turns.
        self._cpu_samples[module].append(cpu_s)
        warmup = self._warmup[module]
        warmup.append(not warmup or compiled)

    def summary(self) -> dict[str, dict[str, Any]]:
        """Per module: ``p50_ms``, ``p95_ms``, ``max_ms``, ``calls`` (steady state), ``cpu_p50_ms`` and
        ``cpu_p95_ms`` (the calling thread's CPU time, steady state), ``warmup_ms``, ``warmup_cpu_ms``
        (the warm-up calls' CPU time) and ``warmup_calls``, ``budget_ms`` and ``over_budget`` (steady
        calls longer than the budget; None without one), and ``histogram`` (steady calls per bin of
        :data:`HISTOGRAM_EDGES_MS`)."""
        out: dict[str, dict[str, Any]] = {}
        for name, values in sorted(self._samples.items()):
            arr = np.asarray(values) * 1e3
            warm = np.asarray(self._warmup[name], dtype=bool)
            steady = arr[~warm]
            cpu_all = np.asarray(self._cpu_samples[name]) * 1e3
            cpu = cpu_all[~warm]
            budget = self.budgets_ms.get(name)
            edges = HISTOGRAM_EDGES_MS
            counts, _ = np.histogram(np.clip(steady, edges[0], edges[-1]), edges)
            out[name] = {
                "p50_ms": float(np.percentile(steady, 50)) if steady.size else None,
                "p95_ms": float(np.percentile(steady, 95)) if steady.size else None,
                "max_ms": float(steady.max()) if steady.size else None,
                "cpu_p50_ms": float(np.percentile(cpu, 50)) if cpu.size else None,
                "cpu_p95_ms": float(np.percentile(cpu, 95)) if cpu.size else None,
                "calls": len(steady),
                "warmup_ms": float(arr[warm].sum()),
                "warmup_cpu_ms": float(cpu_all[warm].sum()),
                "warmup_calls": int(warm.sum()),
                "budget_ms": budget,
                "over_budget": int(np.sum(steady > budget)) if budget is not None else None,
                "histogram": counts.tolist(),
            }
        return out

    def samples_ms(self, module: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every call of ``module`` in order: wall ms, CPU ms and whether it was a warm-up call."""
        wall = np.asarray(self._samples.get(module, []), dtype=float) * 1e3
        cpu = np.asarray(self._cpu_samples.get(module, []), dtype=float) * 1e3
        return wall, cpu, np.asarray(self._warmup.get(module, []), dtype=bool)

    def warmup_s(self) -> float:
        """Wall time of every module's warm-up calls, in seconds."""
        total = 0.0
        for name, values in self._samples.items():
            total += sum(t for t, warm in zip(values, self._warmup[name], strict=True) if warm)
        return total


class _Measurement:
    """One timed call (a plain context manager: entered on every module call of every tick, where a
    generator-based one costs several times more)."""

    __slots__ = ("_compiled_before", "_cpu_start", "_module", "_profiler", "_start")

    def __init__(self, profiler: ModuleProfiler, module: str) -> None:
        self._profiler = profiler
        self._module = module

    def __enter__(self) -> None:
        self._compiled_before = COMPILE_CLOCK.total_s
        self._start = time.perf_counter()
        self._cpu_start = time.thread_time()

    def __exit__(self, *exc: object) -> None:
        wall_s = time.perf_counter() - self._start
        cpu_s = time.thread_time() - self._cpu_start
        self._profiler._record(self._module, wall_s, cpu_s, COMPILE_CLOCK.total_s > self._compiled_before)
