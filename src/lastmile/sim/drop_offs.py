"""The referee's view of passengers' drop-offs between stops: where they got off, how near the kerb, how
long the shuttle stood.

Ground truth only, for the run log. The kerb is the mapped one nearest the door (at a stop, the stop's
own platform kerb, measured as a stop is). A drop-off counts as served once the rider is off and the
shuttle moves again; a run that ends with the shuttle still standing there logs no ``drop_off_served``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.polyline import Polyline
from lastmile.core.run_events import EventKind
from lastmile.sim.judge import BODY_SIDE_SAMPLES, Judge

MOVING_MPS = 0.05
"""The shuttle stands below this speed (the door interlock's threshold)."""


@dataclass(frozen=True, slots=True)
class _Alighting:
    passenger_id: int
    stop_id: str
    curb_gap_m: float
    body_gap_m: float
    route_s_m: float


class DropOffReferee:
    """Logs ``drop_off_requested`` when a rider presses and ``drop_off_served`` when the shuttle leaves
    the place that rider got off at (curb and body gaps, standing time)."""

    def __init__(self, judge: Judge) -> None:
        self.judge = judge
        self._standing_since_s: float | None = None
        self._alighted: list[_Alighting] = []

    def requested(self, passenger_id: int) -> None:
        self.judge.emit(
            EventKind.DROP_OFF_REQUESTED, passenger_id=passenger_id, route_s_m=round(self.judge.route_s_m, 3)
        )

    def alighted(self, passenger_id: int, stop_id: str | None) -> None:
        """The rider is off: measure where the shuttle stands (the door open, at rest)."""
        if stop_id is not None:
            visit = self.judge.open_visit(stop_id)
            door, body = visit.curb_gap_m, visit.body_gap_m
        else:
            door, body = self._kerb_gaps()
        self._alighted.append(
            _Alighting(passenger_id, stop_id or "", door, body, round(self.judge.route_s_m, 3))
        )

    def step(self) -> None:
        """Once a tick: a served drop-off is logged as the shuttle moves off."""
        w = self.judge.world
        if w.ego.state.speed_mps < MOVING_MPS:
            if self._standing_since_s is None:
                self._standing_since_s = w.t_s
            return
        since, self._standing_since_s = self._standing_since_s, None
        if since is None or not self._alighted:
            return
        for a in self._alighted:
            self.judge.emit(
                EventKind.DROP_OFF_SERVED,
                passenger_id=a.passenger_id,
                stop_id=a.stop_id,
                curb_gap_m=a.curb_gap_m,
                body_gap_m=a.body_gap_m,
                wait_s=round(w.t_s - since, 3),
                route_s_m=a.route_s_m,
            )
        self._alighted = []

    def _kerb_gaps(self) -> tuple[float, float]:
        """(door, body) gaps to the mapped kerb nearest the door: from the middle of the door (the
        right side) and the least over the right side, positive with the kerb to the right; NaN
        without a kerb within reach."""
        w = self.judge.world
        s, g = w.ego.state, w.geometry
        c, si = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
        half = g.width_m / 2.0
        door_along = g.length_m / 2.0 - g.rear_overhang_m
        along = np.append(
            np.linspace(-g.rear_overhang_m, g.length_m - g.rear_overhang_m, BODY_SIDE_SAMPLES), door_along
        )
        xs, ys = s.x_m + along * c + half * si, s.y_m + along * si - half * c
        curb = _nearest_curb(w.hdmap.curbs, float(xs[-1]), float(ys[-1]))
        if curb is None:
            return math.nan, math.nan
        right = (si, -c)  # the shuttle's right, where the door opens
        gaps = []
        for x, y in zip(xs.tolist(), ys.tolist(), strict=True):
            f = curb.project(x, y)
            cx, cy_, _ = curb.point_at(f.s_m)
            gaps.append((cx - x) * right[0] + (cy_ - y) * right[1])
        return round(gaps[-1], 4), round(min(gaps), 4)


KERB_REACH_M = 3.0
"""A mapped kerb further than this from the door is not the one the shuttle stopped at."""


def _nearest_curb(curbs: tuple[Polyline, ...], x_m: float, y_m: float) -> Polyline | None:
    best, best_d = None, KERB_REACH_M
    for curb in curbs:
        f = curb.project(x_m, y_m)
        # An open line's projection runs on past its ends: only a foot on the kerb itself counts.
        if not (curb.closed or 0.0 <= f.s_m <= curb.length_m):
            continue
        if abs(f.d_m) < best_d:
            best, best_d = curb, abs(f.d_m)
    return best
