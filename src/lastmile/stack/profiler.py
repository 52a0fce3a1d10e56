"""Per-module compute time: measured for reports only, never used for decisions (the loop owns time)."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

import numpy as np

from lastmile.core import vehicle_messages

HISTOGRAM_EDGES_MS = vehicle_messages.LATENCY_HISTOGRAM_EDGES_MS


class ModuleProfiler:
    """Collects the wall time of each module call; ``summary`` gives p50/p95/max in ms, warm-up apart.

    A module's first call pays for its warm-up (Numba compiling a kernel, first allocations, caches
    filling): up to seconds, against milliseconds in steady state. It is reported as ``warmup_ms`` and
    kept out of the percentiles and of ``calls``, so that neither a latency nor a real-time factor
    mixes the two.
    """

    def __init__(self, budgets_ms: Mapping[str, float] | None = None) -> None:
        self._samples: dict[str, list[float]] = defaultdict(list)
        self.budgets_ms = dict(budgets_ms or {})
        """Each module's cycle budget (its period): calls over it are counted as overruns."""

    @contextmanager
    def measure(self, module: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self._samples[module].append(time.perf_counter() - start)

    def summary(self) -> dict[str, dict[str, Any]]:
        """Per module: ``p50_ms``, ``p95_ms``, ``max_ms``, ``calls`` (steady state), ``warmup_ms``,
        ``budget_ms`` and ``over_budget`` (steady calls longer than the budget; None without one), and
        ``histogram`` (counts of steady calls in the :data:`HISTOGRAM_EDGES_MS` bins)."""
        out: dict[str, dict[str, Any]] = {}
        for name, values in sorted(self._samples.items()):
            arr = np.asarray(values) * 1e3
            steady = arr[1:]
            budget = self.budgets_ms.get(name)
            counts, _ = np.histogram(
                np.clip(steady, HISTOGRAM_EDGES_MS[0], HISTOGRAM_EDGES_MS[-1]), HISTOGRAM_EDGES_MS
            )
            out[name] = {
                "p50_ms": float(np.percentile(steady, 50)) if steady.size else None,
                "p95_ms": float(np.percentile(steady, 95)) if steady.size else None,
                "max_ms": float(steady.max()) if steady.size else None,
                "calls": len(steady),
                "warmup_ms": float(arr[0]),
                "budget_ms": budget,
                "over_budget": int(np.sum(steady > budget)) if budget is not None else None,
                "histogram": counts.tolist(),
            }
        return out

    def warmup_s(self) -> float:
        """Wall time of every module's first call (their warm-up), in seconds."""
        return float(sum(values[0] for values in self._samples.values() if values))
