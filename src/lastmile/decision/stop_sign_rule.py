"""Stop signs as virtual lines with a minimum stop duration (issue #20).

aUToronto (7.1.1): "For stop signs, the Behavior module will pause for a minimum stopping duration and
only check for obstacles before calling LP again to move the vehicle." Here the map's stop-sign lines
(``StopLine.stop_sign_id``: a Lanelet2 ``traffic_sign`` rule of a ``de206`` / ``us:R1-1`` sign, outside
an all-way stop or a signal, whose own rules handle their lines) become stop points: the front stops
``stop_before_line_m`` before the line, stands ``full_stop_s`` below ``stopped_mps`` within
``at_line_m`` of the point, and is then released until it has passed the line. The obstacle check
after the stop is decision's own: the in-path, cut-in and crosswalk rules keep running, as on
aUToronto, and ``give_way_rule`` then holds the shuttle at the same point until the traffic with
priority (the junction's lanelets whose approach has no line) leaves it an acceptable gap.

The parameters are the traffic-light rule's (``TrafficLightRuleConfig``), whose flashing red is the
same stop sign: neither the StVO (Zeichen 206: stop, then give way) nor the UVC 11-703 / MUTCD R1-1
give a duration, only a full stop; ``full_stop_s`` (1 s) is the project's full stop everywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig
from lastmile.hdmap.layers import RouteStopLine, SLayerDatabase


def stop_sign_lines(layers: SLayerDatabase) -> tuple[RouteStopLine, ...]:
    """The route's two-way stop lines: a stop sign's, not an all-way stop's or a signal's."""
    return tuple(
        rl
        for rl in layers.stop_lines
        if rl.stop_line.stop_sign_id is not None
        and rl.stop_line.all_way_stop_id is None
        and rl.stop_line.signal_id is None
    )


@dataclass
class StopSignRule:
    """Stop points for the route's stop signs; ``step`` runs every decision cycle."""

    layers: SLayerDatabase
    config: TrafficLightRuleConfig = field(default_factory=TrafficLightRuleConfig)
    lines: tuple[RouteStopLine, ...] = ()
    _stopped_since_s: dict[int, float] = field(default_factory=dict)
    _cleared: set[int] = field(default_factory=set)

    def __post_init__(self) -> None:
        self.lines = stop_sign_lines(self.layers)

    def step(
        self, t_s: float, front_s_m: float, speed_mps: float, ahead: Callable[[float, float], float]
    ) -> tuple[float | None, str]:
        """(front-bumper stop s or None, why) for the nearest stop-sign line ahead.

        Args:
            ahead: route distance from the front to an s (wrapping on a loop), as the FSM measures it.
        """
        if not self.lines:
            return None, ""
        c = self.config
        best: tuple[float, RouteStopLine] | None = None
        for rl in self.lines:
            d = ahead(rl.s_m, front_s_m)
            if -c.stop_before_line_m < d < c.approach_m and (best is None or d < best[0]):
                best = (d, rl)
        active = best[1].stop_line.id if best is not None else None
        # A line no longer approached (passed) is owed a full stop again next time round.
        self._cleared &= {active} if active is not None else set()
        self._stopped_since_s = {k: v for k, v in self._stopped_since_s.items() if k == active}
        if best is None:
            return None, ""
        dist, rl = best
        line_id = rl.stop_line.id
        if line_id in self._cleared:
            return None, f"stop sign {line_id}: stopped, go"
        gap = dist - c.stop_before_line_m
        if gap < c.at_line_m and speed_mps < c.stopped_mps:
            since = self._stopped_since_s.setdefault(line_id, t_s)
            if t_s - since >= c.full_stop_s:
                self._cleared.add(line_id)
                return None, f"stop sign {line_id}: stopped, go"
        else:
            self._stopped_since_s.pop(line_id, None)
        return rl.s_m - c.stop_before_line_m, f"stop sign {line_id}: stop"
