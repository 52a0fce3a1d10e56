"""The referee at yield lines (give-way lines and two-way stops; issue #20), from ground truth.

Two verdicts, per passage of the shuttle:

- a ``give_way_entry`` event as the front crosses the line: whether it stood within 4 m before the
  line and for how long (the same "at the line" as the stop-line rules');
- a ``failure_to_yield`` violation when the front enters a conflict zone (``hdmap.give_way_zones``)
  while a road user with priority is inside it, or is moving towards it and can no longer stop short
  of it: closer than its stopping sight distance, AASHTO's (Green Book 2018, 3.2.2) 2.5 s brake
  reaction plus braking at 3.4 m/s^2. Such a driver has to brake harder than a design driver would
  or hit the shuttle: the shuttle took its right of way. One that can still stop comfortably was at
  most impeded, which the referee does not judge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.run_events import EventKind
from lastmile.hdmap.give_way_zones import Approach, YieldJunction, yield_junctions, yield_kind
from lastmile.hdmap.model import HDMap, StopLine
from lastmile.sim.agents import Agent

REACTION_S = 2.5
"""AASHTO's brake reaction time for stopping sight distance."""
DECEL_MPS2 = 3.4
"""AASHTO's deceleration for stopping sight distance (11.2 ft/s^2)."""
LOOKBACK_M = 150.0
"""Priority traffic is judged this far upstream of a zone (beyond 30 km/h's sight distance of 31 m)."""
AT_LINE_M = 4.0
"""A stop within this before the line counts (the stop-line rules' reach)."""
STANDING_MPS = 0.2
"""Below this the shuttle stands (the referee's ``stop_speed_mps``)."""
NEAR_M = 80.0
"""Lines farther than this from the shuttle are not looked at this tick."""
_PRIORITY_CLASSES = frozenset({ObjectClass.CAR, ObjectClass.CYCLIST})


def stopping_sight_distance_m(speed_mps: float) -> float:
    """AASHTO's stopping sight distance: reaction at speed, then braking at ``DECEL_MPS2``."""
    v = max(speed_mps, 0.0)
    return v * REACTION_S + v * v / (2.0 * DECEL_MPS2)


@dataclass(slots=True)
class _Passage:
    last_ahead_m: float | None = None
    stood_s: float = 0.0
    entered: set[int] = field(default_factory=set)


@dataclass
class GiveWayReferee:
    """Watches the shuttle at the route's yield lines; ``step`` returns this tick's events."""

    hdmap: HDMap
    route: Polyline
    junctions: tuple[YieldJunction, ...] = ()
    _passages: dict[int, _Passage] = field(default_factory=dict)
    _last_t_s: float | None = None

    def __post_init__(self) -> None:
        lines = [(sl, s) for sl in self.hdmap.stop_lines if (s := self._on_route(sl)) is not None]
        self.junctions = yield_junctions(self.hdmap, self.route, lines, LOOKBACK_M)

    def _on_route(self, line: StopLine) -> float | None:
        """The route s of a yield line the route crosses in the line's direction, else None."""
        if yield_kind(line) is None:
            return None
        x, y = (float(v) for v in line.line.mean(axis=0))
        f = self.route.project(x, y)
        lane = self.hdmap.lanelets[line.lanelet_id].centerline
        along = math.cos(self.route.heading_at(f.s_m) - lane.heading_at(lane.length_m - 0.1))
        return f.s_m if abs(f.d_m) < 4.0 and along > 0.7 else None

    def step(
        self, t_s: float, front_xy: tuple[float, float], speed_mps: float, agents: list[Agent]
    ) -> list[tuple[EventKind, dict[str, object]]]:
        """(kind, data) of this tick's events: a ``GIVE_WAY_ENTRY``, or a ``RULE_VIOLATION`` whose rule
        is ``failure_to_yield``, ready for the judge to emit."""
        out: list[tuple[EventKind, dict[str, object]]] = []
        dt_s = 0.0 if self._last_t_s is None else t_s - self._last_t_s
        self._last_t_s = t_s
        for j in self.junctions:
            mid = j.stop_line.line.mean(axis=0)
            if math.hypot(front_xy[0] - float(mid[0]), front_xy[1] - float(mid[1])) > NEAR_M:
                self._passages.pop(j.stop_line.id, None)
                continue
            f = self.route.project(*front_xy, hint_s_m=j.line_s_m, window_m=NEAR_M)
            ahead = -self.route.ds_m(j.line_s_m, f.s_m)  # line ahead of the front: positive
            p = self._passages.setdefault(j.stop_line.id, _Passage())
            if 0.0 <= ahead <= AT_LINE_M and speed_mps < STANDING_MPS:
                p.stood_s += dt_s
            if p.last_ahead_m is not None and p.last_ahead_m > 0.0 >= ahead:
                out.append(
                    (
                        EventKind.GIVE_WAY_ENTRY,
                        {
                            "stop_line_id": j.stop_line.id,
                            "line_kind": j.kind.value,
                            "stopped_before": p.stood_s > 0.0,
                            "stood_s": round(p.stood_s, 2),
                        },
                    )
                )
                p.stood_s = 0.0
            for k, zone in enumerate(j.zones):
                if k in p.entered or p.last_ahead_m is None:
                    continue
                if p.last_ahead_m > -zone.start_after_line_m >= ahead:
                    p.entered.add(k)
                    out += [
                        (
                            EventKind.RULE_VIOLATION,
                            {"rule": "failure_to_yield", "detail": f"stop line {j.stop_line.id}: {why}"},
                        )
                        for why in _forced(zone.approaches, agents)
                    ]
            if ahead > 0.0:
                p.entered.clear()
            p.last_ahead_m = ahead
        return out


def _forced(approaches: tuple[Approach, ...], agents: list[Agent]) -> list[str]:
    """Road users with priority in a zone, or that can no longer stop short of it."""
    out = []
    for a in agents:
        if not a.active or a.cls not in _PRIORITY_CLASSES:
            continue
        for approach in approaches:
            line = approach.centerline
            f = line.project(a.x_m, a.y_m)
            if abs(f.d_m) > approach.half_width_m or f.s_m < 0.0:
                continue
            front, rear = f.s_m + a.length_m / 2.0, f.s_m - a.length_m / 2.0
            along = a.speed_mps * math.cos(a.yaw_rad - line.heading_at(f.s_m))
            if rear > approach.zone_end_m or along < -0.5:
                continue
            if front >= approach.zone_start_m:
                out.append(f"{a.cls.name.lower()} {a.id} in the conflict zone")
                break
            gap = approach.zone_start_m - front
            if along > 0.5 and gap < stopping_sight_distance_m(along):
                out.append(
                    f"{a.cls.name.lower()} {a.id} {gap:.1f} m from the conflict zone at {along:.1f} m/s "
                    f"(stopping sight distance {stopping_sight_distance_m(along):.1f} m)"
                )
                break
    return out
