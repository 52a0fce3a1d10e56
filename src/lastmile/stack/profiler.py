"""Per-module compute time: measured for reports only, never used for decisions (the loop owns time)."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np


class ModuleProfiler:
    """Collects the wall time of each module call; ``summary`` gives p50/p95/max in ms."""

    def __init__(self) -> None:
        self._samples: dict[str, list[float]] = defaultdict(list)

    @contextmanager
    def measure(self, module: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self._samples[module].append(time.perf_counter() - start)

    def summary(self) -> dict[str, dict[str, float]]:
        out: dict[str, dict[str, float]] = {}
        for name, values in sorted(self._samples.items()):
            arr = np.asarray(values) * 1e3
            out[name] = {
                "p50_ms": float(np.percentile(arr, 50)),
                "p95_ms": float(np.percentile(arr, 95)),
                "max_ms": float(arr.max()),
                "calls": len(values),
            }
        return out
