"""Time as integer microseconds: no float seconds inside messages, no wall clock inside the loop."""

from __future__ import annotations

from typing import NewType

Stamp = NewType("Stamp", int)
"""Microseconds since the start of the run (simulated time on the simulator's clock)."""

US_PER_S = 1_000_000


def stamp_from_s(t_s: float) -> Stamp:
    """Round seconds to the nearest microsecond."""
    return Stamp(round(t_s * US_PER_S))


def s_from_stamp(stamp: int) -> float:
    """Seconds as a float, for arithmetic outside messages."""
    return stamp / US_PER_S
