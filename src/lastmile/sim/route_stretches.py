"""Where on a service route the scenario generator may stage an encounter: the route's own free stretches.

A generated encounter (a walker stepping out, a goose, an obstacle in the lane) should be one hazard at a
time, so it is placed away from what the shuttle already handles there: its stops (pulling over and
leaving), the junctions it passes (other traffic, all-way stops) and the crosswalks on its path (their
own pedestrians). The clearance is the farthest a walker's trigger reaches ahead of the shuttle
(``ScenarioSpace.trigger_m``): closer than that, the encounter and the place overlap in time.
"""

from __future__ import annotations

from lastmile.core.errors import ConfigError
from lastmile.hdmap.service_route import ServiceRoute

MIN_STRETCH_M = 20.0
"""A free stretch shorter than this is dropped: a walker's crossing and the shuttle's stop before it
need about this much road (an 8 m braking distance at 5.5 m/s and 1.83 m/s², plus the body)."""


def free_stretches(service: ServiceRoute, clearance_m: float) -> tuple[tuple[float, float], ...]:
    """Intervals of route s (m, within [0, length)) at least ``clearance_m`` from every stop, junction
    and crosswalk on the service path, each at least MIN_STRETCH_M long.

    Raises:
        ConfigError: no such stretch on the route (every part of it is near a stop, junction or
            crosswalk), naming the route and the clearance asked for.
    """
    length = service.length_m
    places = [(stop.route_s_m, stop.route_s_m) for stop in service.stops]
    places += service.intersections()
    places += [(c.s_start_m, c.s_end_m) for c in service.layers(step_m=1.0).crosswalks]
    blocked = _merged([(lo - clearance_m, hi + clearance_m) for lo, hi in places], length)
    free = _complement(blocked, length)
    kept = tuple((round(lo, 1), round(hi, 1)) for lo, hi in free if hi - lo >= MIN_STRETCH_M)
    if not kept:
        raise ConfigError(
            f"route {service.name!r}: expected a stretch of at least {MIN_STRETCH_M:.0f} m that is "
            f"{clearance_m:.0f} m clear of stops, junctions and crosswalks for generated encounters, "
            f"got none on its {length:.0f} m loop"
        )
    return kept


def _merged(intervals: list[tuple[float, float]], length_m: float) -> list[tuple[float, float]]:
    """The union of intervals on a closed loop of ``length_m``, as sorted intervals within [0, length)."""
    pieces: list[tuple[float, float]] = []
    for lo, hi in intervals:
        if hi - lo >= length_m:
            return [(0.0, length_m)]
        lo_w, hi_w = lo % length_m, hi % length_m
        if lo_w <= hi_w:
            pieces.append((lo_w, hi_w))
        else:  # wraps past the loop's start
            pieces += [(lo_w, length_m), (0.0, hi_w)]
    pieces.sort()
    out: list[tuple[float, float]] = []
    for lo, hi in pieces:
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def _complement(blocked: list[tuple[float, float]], length_m: float) -> list[tuple[float, float]]:
    free, at = [], 0.0
    for lo, hi in blocked:
        if lo > at:
            free.append((at, lo))
        at = max(at, hi)
    if at < length_m:
        free.append((at, length_m))
    return free
