"""The indicator lights the actuator command carries (issue #20).

aUToronto (7.1.1) has its behaviour layer toggle the indicator lights during lane changes and turns;
the pull-over, merge and pass of WATonoBus's and our decision are lateral moves of the same kind. Each
control step :meth:`TurnSignalRule.signal` picks one state, by priority:

1. hazard: an emergency stop (decision's state, or a command that asks for the emergency brake) and a
   minimal-risk manoeuvre (a stop whose reason is one);
2. right while pulling over (a stop or a passenger's drop-off), left while merging out (waiting for
   traffic behind included); off while boarding in the bay (the move out is announced once it merges);
3. a pass of a stationary obstacle: left while moving out (the front still short of the obstacle's
   rear), right while coming back (the front past its front), off alongside it;
4. the route's own manoeuvres ahead: a turn at a junction (the route lanelet's ``turn_direction`` tag,
   Autoware's convention; an untagged junction lanelet by its heading change) and a lane change
   (consecutive route lanelets side by side, by their shared bound), switched on ``advance_m`` before
   the manoeuvre starts and off once the whole body is through it.

``advance_m`` is 100 ft (30.48 m): the signal "continuously during not less than the last 100 feet
traveled by the vehicle before turning" of the Uniform Vehicle Code 11-604(b) (California Vehicle Code
22108). The StVO (9 (1)) asks for it "rechtzeitig" without a figure.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, StopReason, TurnSignal
from lastmile.hdmap.layers import DRIVEWAY, INTERSECTION, SLayerDatabase
from lastmile.hdmap.model import LaneletInfo

UVC_SIGNAL_DISTANCE_M = 30.48  # 100 ft, UVC 11-604(b) / CVC 22108
MIN_LANE_OFFSET_M = 1.75
"""A route lanelet that starts at least this far beside the last one (half a 3.5 m lane; our choice,
not from a source) is a lane over, for maps whose neighbouring lanes do not share a bound."""


class ManoeuvreKind(Enum):
    TURN = "turn"
    LANE_CHANGE = "lane_change"


@dataclass(frozen=True, slots=True, kw_only=True)
class TurnSignalConfig:
    """Attributes:
    advance_m: how far before a turn or lane change the indicator goes on (UVC 11-604(b): 100 ft).
    untagged_turn_min_rad: the heading change through a junction lanelet without a
        ``turn_direction`` tag that counts as a turn. Not from a source: halfway between going
        straight and a right-angle turn.
    """

    advance_m: float = UVC_SIGNAL_DISTANCE_M
    untagged_turn_min_rad: float = math.pi / 4.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.advance_m) and self.advance_m >= 0.0):
            raise ConfigError(f"TurnSignalConfig.advance_m: expected a distance >= 0 m, got {self.advance_m}")
        if not 0.0 < self.untagged_turn_min_rad < math.pi:
            raise ConfigError(
                "TurnSignalConfig.untagged_turn_min_rad: expected an angle in (0, pi), "
                f"got {self.untagged_turn_min_rad}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class RouteManoeuvre:
    """A turn or lane change on the route: front-bumper route s where it starts and ends."""

    kind: ManoeuvreKind
    signal: TurnSignal
    start_s_m: float
    end_s_m: float
    lanelet_id: int


def route_manoeuvres(layers: SLayerDatabase, untagged_turn_min_rad: float) -> tuple[RouteManoeuvre, ...]:
    """The turns and lane changes along the route, in s order (from the s-layer's lanelet runs)."""
    runs = _lanelet_runs(layers)
    lanelets = layers.hdmap.lanelets
    out: list[RouteManoeuvre] = []
    for k, (lid, i0, i1) in enumerate(runs):
        start_s, end_s = float(layers.s_m[i0]), float(layers.s_m[i1 - 1]) + layers.step_m
        info = lanelets.get(lid)
        if info is None:
            continue
        turn = _turn_of(layers, info, i0, i1, untagged_turn_min_rad)
        if turn is not TurnSignal.OFF:
            out.append(
                RouteManoeuvre(
                    kind=ManoeuvreKind.TURN, signal=turn, start_s_m=start_s, end_s_m=end_s, lanelet_id=lid
                )
            )
        if k > 0:
            side = _lane_change_side(layers, runs[k - 1][0], lid)
            if side is not TurnSignal.OFF:
                out.append(
                    RouteManoeuvre(
                        kind=ManoeuvreKind.LANE_CHANGE,
                        signal=side,
                        start_s_m=start_s,
                        end_s_m=start_s,
                        lanelet_id=lid,
                    )
                )
    return tuple(out)


def _lanelet_runs(layers: SLayerDatabase) -> list[tuple[int, int, int]]:
    """(lanelet id, first record, one past the last record) of each run of equal route lanelet."""
    ids = layers.lanelet_id
    if ids.size == 0:
        return []
    cuts = np.flatnonzero(ids[1:] != ids[:-1]) + 1
    bounds = [0, *cuts.tolist(), int(ids.size)]
    return [(int(ids[a]), a, b) for a, b in itertools.pairwise(bounds)]


def _turn_of(layers: SLayerDatabase, info: LaneletInfo, i0: int, i1: int, min_rad: float) -> TurnSignal:
    """A turning lanelet: its ``turn_direction`` tag, else (in a junction) its heading change."""
    if info.turn == "left":
        return TurnSignal.LEFT
    if info.turn == "right":
        return TurnSignal.RIGHT
    if info.turn == "straight":
        return TurnSignal.OFF
    junction = np.isin(layers.road_type[i0:i1], (INTERSECTION, DRIVEWAY)).any()
    if not junction:
        return TurnSignal.OFF
    line = layers.centerline
    s0, s1 = float(layers.s_m[i0]), min(float(layers.s_m[i1 - 1]) + layers.step_m, line.length_m)
    change = (line.heading_at(s1) - line.heading_at(s0) + math.pi) % (2.0 * math.pi) - math.pi
    if abs(change) < min_rad:
        return TurnSignal.OFF
    return TurnSignal.LEFT if change > 0.0 else TurnSignal.RIGHT


def _lane_change_side(layers: SLayerDatabase, before_id: int, after_id: int) -> TurnSignal:
    """The side of a lane change from ``before_id`` to ``after_id`` (not its successor): by the bound
    they share, else by where the new lane lies beside the old one."""
    hdmap = layers.hdmap
    before, after = hdmap.lanelets.get(before_id), hdmap.lanelets.get(after_id)
    if before is None or after is None or after_id in hdmap.successors(before_id):
        return TurnSignal.OFF
    side = _side_by_side(before, after)
    if side is not TurnSignal.OFF:
        return side
    # Bounds drawn twice: where the new lane starts beside the old one (or, when it starts beyond the
    # old one's end, where the old one ends beside the new one).
    x0, y0 = (float(v) for v in after.centerline.xy_m[0])
    p = before.centerline.project(x0, y0)
    if 0.0 < p.s_m < before.centerline.length_m:
        offset = p.d_m
    else:
        x1, y1 = (float(v) for v in before.centerline.xy_m[-1])
        offset = -after.centerline.project(x1, y1).d_m
    if abs(offset) < MIN_LANE_OFFSET_M:
        return TurnSignal.OFF
    return TurnSignal.LEFT if offset > 0.0 else TurnSignal.RIGHT


def _side_by_side(before: LaneletInfo | None, after: LaneletInfo | None) -> TurnSignal:
    """Left when ``after`` lies left of ``before`` (they share a bound), right when right of it."""
    if before is None or after is None:
        return TurnSignal.OFF
    if before.left_bound_id and before.left_bound_id == after.right_bound_id:
        return TurnSignal.LEFT
    if before.right_bound_id and before.right_bound_id == after.left_bound_id:
        return TurnSignal.RIGHT
    return TurnSignal.OFF


class TurnSignalRule:
    """Picks the indicator state each control step (module docstring)."""

    def __init__(
        self, layers: SLayerDatabase, body_length_m: float, config: TurnSignalConfig | None = None
    ) -> None:
        self.config = config or TurnSignalConfig()
        self.route = layers.centerline
        self.body_length_m = body_length_m
        self.manoeuvres = route_manoeuvres(layers, self.config.untagged_turn_min_rad)
        self._last = TurnSignal.OFF
        self._switched_on = dict.fromkeys((TurnSignal.LEFT, TurnSignal.RIGHT, TurnSignal.HAZARD), 0)

    def counters(self) -> dict[str, int]:
        """How often each indicator state was switched on (the stack's report)."""
        return {f"turn_signal_{k.value}_on": n for k, n in self._switched_on.items()}

    def signal(
        self, decision: BehaviourDecision, front_s_m: float, emergency_brake: bool = False
    ) -> TurnSignal:
        """The indicator state for this step (counted when it changes); ``front_s_m`` is the front
        bumper's route s."""
        out = self._signal(decision, front_s_m, emergency_brake)
        if out is not self._last and out is not TurnSignal.OFF:
            self._switched_on[out] += 1
        self._last = out
        return out

    def _signal(self, decision: BehaviourDecision, front_s_m: float, emergency_brake: bool) -> TurnSignal:
        if (
            emergency_brake
            or decision.state is BehaviourState.EMERGENCY_STOP
            or decision.stop_reason is StopReason.MINIMAL_RISK_MANOEUVRE
        ):
            return TurnSignal.HAZARD
        if decision.state is BehaviourState.PULLOVER:
            return TurnSignal.RIGHT
        if decision.state is BehaviourState.MERGING:
            return TurnSignal.LEFT
        if decision.state is BehaviourState.ONBOARDING:
            return TurnSignal.OFF  # standing in the bay, doors working: no move to announce yet
        passing = self._pass_signal(decision, front_s_m)
        if passing is not None:
            return passing
        return self._route_signal(front_s_m)

    def _pass_signal(self, decision: BehaviourDecision, front_s_m: float) -> TurnSignal | None:
        """Out left before the obstacle, back right after it, off alongside; None: no pass driven."""
        req = decision.pass_request
        if req is None or not (req.approved or req.committed):
            return None
        if self.route.ds_m(front_s_m, req.start_s_m) > 0.0:
            return TurnSignal.LEFT
        if self.route.ds_m(req.end_s_m, front_s_m) > 0.0:
            return TurnSignal.RIGHT
        return TurnSignal.OFF

    def _route_signal(self, front_s_m: float) -> TurnSignal:
        """The nearest route manoeuvre whose signalling window holds the front bumper."""
        best, best_ahead = TurnSignal.OFF, math.inf
        for m in self.manoeuvres:
            ahead = self.route.ds_m(front_s_m, m.start_s_m)
            through_m = (m.end_s_m - m.start_s_m) + self.body_length_m
            if -through_m <= ahead <= self.config.advance_m and ahead < best_ahead:
                best, best_ahead = m.signal, ahead
        return best
