"""Reference operations the benchmarks time beside their own figures, so that a figure from a loaded or
slower machine can be read against the machine's speed at that moment."""

from __future__ import annotations

import time

import numpy as np


def matrix_products_ms() -> float:
    """CPU ms of 1,000 products of two 64 x 64 matrices (BLAS pinned to one thread by the caller)."""
    a = np.random.default_rng(0).standard_normal((64, 64))
    start = time.process_time()
    for _ in range(1000):
        a = (a @ a) / 64.0
    return (time.process_time() - start) * 1e3
