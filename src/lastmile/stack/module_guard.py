"""Runs each module call contained, and turns how it ended into the module's heartbeat.

The vehicle's safety (apart from the stack) watches these heartbeats; the guard only reports. A module
that raises yields an unhealthy pulse naming the exception, and the tick goes on without its result.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import Heartbeat


class ModuleGuard:
    """Contains module failures and collects the tick's heartbeats, in call order."""

    def __init__(self) -> None:
        self._beats: list[Heartbeat] = []

    def call(self, module: str, now: Stamp, fn: Callable[..., Any], /, *args: Any) -> Any:
        """``fn(*args)``, or None when it raised (the exception becomes an unhealthy pulse)."""
        try:
            result = fn(*args)
        except Exception as exc:  # containment is the point: any module failure becomes a heartbeat
            self._beats.append(
                Heartbeat(
                    stamp=now,
                    module=module,
                    healthy=False,
                    reason=f"{type(exc).__name__}: {exc}",
                    exception=True,
                )
            )
            return None
        self._beats.append(Heartbeat(stamp=now, module=module, healthy=True))
        return result

    def drain(self) -> tuple[Heartbeat, ...]:
        """The heartbeats since the last drain (one tick's)."""
        beats, self._beats = tuple(self._beats), []
        return beats
