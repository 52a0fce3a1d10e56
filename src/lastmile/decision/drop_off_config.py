"""Parameters of the seat-button drop-off (``decision.drop_off``), with their sources."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.errors import ConfigError


@dataclass(frozen=True, slots=True, kw_only=True)
class DropOffConfig:
    """Parameters of the drop-off (units in names; sources beside each).

    Attributes:
        wait_s: how long the shuttle stays halted at least (Snow Lion: "a predefined period (typically
            8 s)").
        clear_radius_m: no pedestrian, cyclist or animal track may be this close to the body on the
            door's side before it moves off. Snow Lion gives no figure; ours: a person walking at
            1.2 m/s (the MUTCD's walking speed for signal timing, 4E.06, rounded up from 3.5 ft/s)
            covers 3 m in 2.5 s, the perception-reaction time AASHTO's stopping sight distance assumes.
        clear_for_s: ... for this long without a break (a radar track of someone standing still is
            confirmed on some frames only; the pass rule's ``clear_for_s``).
        crosswalk_clear_m: the body stays this far from a crosswalk, either side (StVO 12(1): no halting
            on a pedestrian crossing nor within 5 m before it; after it we keep the same, since a
            shuttle just past the crossing hides people stepping out behind it).
        junction_clear_m: ... from an intersection box or a driveway (StVO 12(3): no parking within 5 m
            of the edges of crossing carriageways).
        stop_line_clear_m: ... before a stop line (StVO 12(1): no halting within 10 m before a traffic
            light or sign it would hide; a stop line stands at one).
        max_curvature_1pm: no stop where the route bends more sharply (StVO 12(1): no halting at sharp
            bends, which it leaves undefined; we take a radius under 100 m, which rules out the campus
            corners (40 m) and town turns and keeps gently curving streets).
        kerb_lane_edge_m: the kerb must be within this of the lane's right edge (it is the lane's own
            edge): further out is a bay, its taper, a parking lane or another lane. 0.1 m: the rest
            offset is laid for the lane's edge, and a kerb 0.1 m further out already puts the door at
            the service's 0.3 m curb-gap limit (0.2 m target + 0.1 m).
        search_m: how far ahead the search looks on a route without stops (or beyond the last one).
    """

    wait_s: float = 8.0
    clear_radius_m: float = 3.0
    clear_for_s: float = 1.0
    crosswalk_clear_m: float = 5.0
    junction_clear_m: float = 5.0
    stop_line_clear_m: float = 10.0
    max_curvature_1pm: float = 0.01
    kerb_lane_edge_m: float = 0.1
    search_m: float = 400.0

    def __post_init__(self) -> None:
        for name in ("wait_s", "clear_radius_m", "clear_for_s", "crosswalk_clear_m", "junction_clear_m"):
            _check_at_least(name, getattr(self, name), 0.0)
        _check_at_least("stop_line_clear_m", self.stop_line_clear_m, 0.0)
        for name in ("max_curvature_1pm", "kerb_lane_edge_m", "search_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ConfigError(f"DropOffConfig.{name}: expected a finite number > 0, got {value!r}")


def _check_at_least(name: str, value: object, low: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= low):
        raise ConfigError(f"DropOffConfig.{name}: expected a finite number >= {low}, got {value!r}")
