"""Deterministic id sources (no global counters: each owner holds its own)."""

from __future__ import annotations

import itertools


class IdSource:
    """Hands out increasing integer ids from ``start``."""

    def __init__(self, start: int = 1) -> None:
        self._counter = itertools.count(start)

    def next(self) -> int:
        return next(self._counter)
