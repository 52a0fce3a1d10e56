"""Parameters of the pass rule (:mod:`lastmile.decision.pass_rule`): when a stationary obstacle is passed."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.errors import ConfigError


@dataclass(frozen=True, slots=True, kw_only=True)
class PassConfig:
    """Parameters of :class:`PassRule` (units in names).

    Attributes:
        stationary_speed_mps: slower than this a track counts as standing (radar speed noise of a
            parked car is a few cm/s).
        moving_speed_mps: a standing track's clock restarts only when it moves faster than this (the
            speed estimate of a parked car wanders up to about 0.4 m/s as the shuttle closes in).
        stationary_s: how long it must have stood (a car stopping to let someone out stands less; a
            queue moves within a few seconds of its light).
        lookahead_m: obstacles further ahead of the front than this are not considered yet.
        clearance_m: lateral gap between the shuttle's side and the obstacle it passes: the in-path
            test's ``corridor_margin_m`` (0.5 m), the lateral control error, and the drift of a radar
            track towards the side the radar sees it from (0.3 m for a car passed on its left).
        control_clear_m: an obstacle whose front is within this of a stop line, crosswalk or junction
            ahead is waiting at it.
        queue_gap_m: another road user in the lane this close ahead of the obstacle makes it a queue.
        fragment_gap_m: standing tracks in the lane this close to each other along the road are one
            obstacle (LiDAR clusters split a parked car into several tracks; cars in a queue stand
            1-2 m apart or more).
        wait_gap_m: the front waits this far behind an obstacle it may pass later: room for the rear axle
            to move out (12.6 m for a 2.7 m move at 0.8 of its comfortable length) before the front
            reaches the obstacle, and a view past it: from 20 m behind a car, 0.3 m left of the lane
            centre, the oncoming lane's centre line is in view for 107 m (80 m from 15 m behind).

        wait_decel_mps2: that point is taken only if reachable at this deceleration (the comfortable
            1 m/s^2 of the minimal risk manoeuvre); otherwise the in-path stop point holds.
        transition_m: route length of each lateral move (out and back) the manoeuvre is reckoned with: at
            least the planner's longest (the quintic's comfortable length for a 2.7 m move at 4 m/s and
            1 m/s^2 lateral, 15.8 m).
        return_gap_m: the body's rear clears the obstacle's front by this before the move back begins.
        pass_speed_mps: the speed cap while passing, and the speed the manoeuvre's time is reckoned with.
        accel_mps2: the acceleration the time is reckoned with up to ``pass_speed_mps``.
        time_margin_s: margin on the manoeuvre's time in the oncoming-traffic check.
        oncoming_gap_m: the least gap between the shuttle's front and an oncoming road user.
        sight_m: how far ahead the stack sees oncoming traffic (the front radar's 100 m, less margin).
            A road user beyond it, coming at the speed limit, must be able to stop before the
            shuttle's way back (``oncoming_gap_m`` short) after ``oncoming_reaction_s`` (a driver's
            1.5 s) braking at ``oncoming_decel_mps2`` (2 m/s^2, well under a car's 3-4 m/s^2 of
            firm braking), or arrive only after the manoeuvre.
        clear_for_s: the adjacent lane must have been clear this long before a pass begins (a road
            user coming out of the obstacle's radar shadow is detected on some frames only).
        lookout_margin_m: waiting to pass, the shuttle holds at the left of its lane, its side this far
            inside the lane's boundary, to see past the obstacle.
        min_start_gap_m: a pass is begun only with the front this far behind the obstacle (the rear
            axle has to move out over the quintic before the front reaches it); a shuttle standing
            closer waits (it does not reverse).
        commit_d_m: the shuttle's lateral offset past which a begun pass is finished.
        adjacent_width_m: width of the adjacent lane searched for oncoming traffic.
        passable_left_types: Lanelet2 boundary ``type:subtype`` strings the shuttle may cross to pass a
            stationary obstacle (broken lines; a virtual line). Solid lines: not (the rule in most of
            Europe; some jurisdictions allow crossing a solid centre line to pass an obstruction:
            add ``line_thin:solid`` there).
    """

    stationary_speed_mps: float = 0.3
    stationary_s: float = 3.0
    moving_speed_mps: float = 1.0
    lookahead_m: float = 50.0
    clearance_m: float = 1.0
    control_clear_m: float = 20.0
    queue_gap_m: float = 15.0
    fragment_gap_m: float = 1.0
    wait_gap_m: float = 20.0
    wait_decel_mps2: float = 1.0
    transition_m: float = 16.0
    return_gap_m: float = 1.0
    pass_speed_mps: float = 4.0
    accel_mps2: float = 0.8
    time_margin_s: float = 3.0
    oncoming_gap_m: float = 10.0
    sight_m: float = 90.0
    oncoming_reaction_s: float = 1.5
    oncoming_decel_mps2: float = 2.0
    min_start_gap_m: float = 10.0
    clear_for_s: float = 1.0
    lookout_margin_m: float = 0.45
    commit_d_m: float = 0.3
    adjacent_width_m: float = 3.5
    passable_left_types: tuple[str, ...] = ("line_thin:dashed", "line_thick:dashed", "virtual")

    def __post_init__(self) -> None:
        for name in ("stationary_s", "wait_gap_m", "transition_m", "pass_speed_mps", "accel_mps2", "sight_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(f"DecisionConfig.passing.{name}: expected a positive number, got {value!r}")
