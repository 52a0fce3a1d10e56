"""Which absolute measurement last held the position to the map, and when: the estimate's ``source``."""

from __future__ import annotations

import math

from lastmile.core.errors import ConfigError
from lastmile.core.vehicle_messages import PositionSource

DEAD_RECKONING_AFTER_S = 1.0
"""Without an accepted absolute correction for this long the estimate is dead reckoning, s: four missed
epochs of a 4 Hz RTK receiver (the slowest rate we take in), ten of the simulator's 10 Hz."""


class AbsoluteUpdates:
    """Keeps the stamp of the newest accepted absolute correction per source (GNSS, landmarks, scans)."""

    def __init__(self, timeout_s: float = DEAD_RECKONING_AFTER_S) -> None:
        if not (timeout_s > 0 and math.isfinite(timeout_s)):
            raise ConfigError(f"dead_reckoning_after_s: expected a positive number, got {timeout_s!r}")
        self._timeout_us = round(timeout_s * 1e6)
        self._last_us: dict[PositionSource, int] = {}

    def note(self, source: PositionSource, stamp_us: int) -> None:
        """An absolute correction from ``source`` was accepted at ``stamp_us``."""
        if stamp_us > self._last_us.get(source, -1):
            self._last_us[source] = int(stamp_us)

    def forget(self) -> None:
        """The filter restarted: nothing absolute holds it any more."""
        self._last_us.clear()

    def source_at(self, stamp_us: int) -> PositionSource:
        """LANDMARKS while landmark corrections are current (within the timeout of ``stamp_us``), else
        SCAN_MATCHING while scan-to-map matches are, else AMCL while particle-filter fixes are, else GNSS
        while fixes are, else dead reckoning.
        The map-based sources come first: while they hold the pose it
        does not depend on the receiver, so the loss of a fix must not read as the loss of the
        position (with both at 10 Hz the newest of the two would flip with their phase). An estimate
        for a past stamp counts the corrections up to now (replayed history)."""
        for source in _PRIORITY:
            at_us = self._last_us.get(source)
            if at_us is not None and stamp_us - at_us <= self._timeout_us:
                return source
        return PositionSource.DEAD_RECKONING


_PRIORITY = (PositionSource.LANDMARKS, PositionSource.SCAN_MATCHING, PositionSource.AMCL, PositionSource.GNSS)
