"""The safety driver: when would a human take over? Judged from ground truth, never seen by the stack."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.run_events import EventKind
from lastmile.sim.judge import Judge


@dataclass(frozen=True, slots=True, kw_only=True)
class OperatorConfig:
    """When the operator intervenes (DESIGN.md section 6).

    Attributes:
        imminent_ttc_s: time to collision under which an unresolved conflict makes them brake.
        resolving_decel_mps2: the stack is seen to resolve a conflict if it already brakes this hard.
        stall_s: standing still this long without a cause (nothing close ahead, no riders moving, no
            open door) makes them take over.
        hold_s: how long the operator keeps control before handing back.
    """

    imminent_ttc_s: float = 0.8
    resolving_decel_mps2: float = 2.0
    stall_s: float = 60.0
    hold_s: float = 3.0


class OperatorModel:
    """Counts takeovers and, while in control, holds the brake."""

    def __init__(self, judge: Judge, config: OperatorConfig | None = None) -> None:
        self.judge = judge
        self.config = config or OperatorConfig()
        self.in_control_until_s = -1.0
        self._stopped_since: float | None = None
        self._off_road_seen = False

    @property
    def in_control(self) -> bool:
        return self.judge.world.t_s < self.in_control_until_s

    def step(self, stack_requests_takeover: bool, door_open: bool) -> None:
        w, c = self.judge.world, self.config
        if self.in_control:
            if stack_requests_takeover:
                # The stack still asks for the driver: they keep control (one takeover, not many).
                self.in_control_until_s = w.t_s + c.hold_s
            return
        s = w.ego.state
        reason = ""
        ttc, _ = self.judge.time_to_collision()
        if ttc < c.imminent_ttc_s and s.accel_mps2 > -c.resolving_decel_mps2 and s.speed_mps > 0.5:
            reason = "imminent_collision"
        elif self.judge.off_road and not self._off_road_seen:
            reason = "left_drivable_area"
        elif stack_requests_takeover:
            reason = "stack_request"
        self._off_road_seen = self.judge.off_road
        if s.speed_mps < 0.05 and not door_open and not self._cause_to_stand():
            if self._stopped_since is None:
                self._stopped_since = w.t_s
            elif w.t_s - self._stopped_since > c.stall_s:
                reason = reason or "stall"
        else:
            self._stopped_since = None
        if reason:
            self.judge.emit(EventKind.TAKEOVER, reason=reason)
            self.in_control_until_s = w.t_s + c.hold_s
            self._stopped_since = None

    def _cause_to_stand(self) -> bool:
        """Something within 20 m ahead, or a queue at an all-way stop, explains standing.

        A queue explains it only while its vehicles arrived less than ``stall_s`` ago: turns at an
        all-way stop take seconds each, so a vehicle that has waited that long is in a deadlock with
        the shuttle (each judging the other first: 300 s at the example town's T in snow, no
        takeover), which a safety driver resolves like any other stall.
        """
        w = self.judge.world

        fx, fy = w.ego_front()
        yaw = w.ego.state.yaw_rad
        c, si = math.cos(yaw), math.sin(yaw)
        for a in w.agents:
            if not a.active:
                continue
            dx, dy = a.x_m - fx, a.y_m - fy
            along = dx * c + dy * si
            if -2.0 < along < 20.0 and abs(-dx * si + dy * c) < 12.0:
                return True
        return w.anyone_waiting_at_all_way_stops(arrived_after_s=w.t_s - self.config.stall_s)
