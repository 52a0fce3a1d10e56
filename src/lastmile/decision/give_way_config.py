"""Parameters of the give-way rule: gap acceptance at give-way lines and two-way stops (issue #20)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lastmile.core.errors import ConfigError


@dataclass(frozen=True, slots=True, kw_only=True)
class GiveWayConfig:
    """When the shuttle may cross in front of traffic with priority (``decision.give_way_rule``).

    The gap a road user with priority must leave is the larger of the critical headway a driver of
    the same movement accepts (HCM) and the time the shuttle itself needs to clear the conflict zone,
    plus a margin: a low-speed shuttle pulling away gently needs longer than a car.

    Attributes:
        enabled: act on give-way lines and check the gap after a two-way stop's full stop (off: give-way
            lines are driven through as before, and a two-way stop is a full stop, then on).
        critical_gap_right_s, critical_gap_through_s, critical_gap_left_s: HCM 7th ed. (2022), Exhibit
            20-11, base critical headways for passenger cars at two-way stop-controlled junctions on a
            two-lane major street: minor-street right turn 6.2 s, through 6.5 s, left turn 7.1 s. (The
            follow-up headways of the same exhibit, 3.3 / 4.0 / 3.5 s, size the capacity of a queue of
            minor-street vehicles; a single shuttle has no use for them.)
        clearance_accel_mps2: the acceleration the shuttle clears the zone with: the longitudinal
            law's nominal acceleration a_nom (WATonoBus eq. (1); ``control.longitudinal``'s 0.8 m/s^2).
        clearance_lateral_accel_mps2: through the junction the shuttle goes no faster than
            sqrt(a_lat / curvature) of its route (control's comfort bound, 1.0 m/s^2).
        clearance_margin_s: the priority road user must arrive at the zone at least this long after
            the shuttle's rear has left it: the post-encroachment time the shuttle leaves (Allen et al.
            1978). Our choice, stated: 1.5 s, where the traffic-conflict literature commonly reads a
            post-encroachment time below 1-1.5 s as a serious conflict.
        approach_m: a yield line this close ahead of the front is acted on (the traffic-light rule's).
        lookback_m: priority traffic is looked for this far upstream of a conflict zone: 7.1 s (the
            longest critical gap) at 50 km/h is 98.6 m.
        moving_mps: a road user slower than this along its lane is standing: it does not arrive (one
            inside the zone blocks it). A parked car's radar track wanders up to ~0.4 m/s.
        lateral_margin_m: a road user within half the lane's width plus this of an approach's centre
            line is on it (the radar's position error; the next lane's centre is a lane width away).
        heading_cos_min: a moving road user is on an approach only while its velocity is within
            acos(this) = 60 degrees of the lane's direction (not crossing it, not oncoming).
        lost_track_s: a road user seen on an approach whose track is then lost (it leaves the radar's
            field of view as the shuttle comes up to the line: the front radar's 75 degrees) is still
            expected, at its last speed, until it would have left the zone, for at most this long (our
            choice: 10 s, longer than any gap needed on the example town's turns).
        zone_margin_m: a shuttle that can no longer stop comfortably at the line stops its front this far
            short of the conflict zone instead, when it can (our choice: 1 m, several times the
            position error of localization and the stop's overshoot).
    """

    enabled: bool = True
    critical_gap_right_s: float = 6.2
    critical_gap_through_s: float = 6.5
    critical_gap_left_s: float = 7.1
    clearance_accel_mps2: float = 0.8
    clearance_lateral_accel_mps2: float = 1.0
    clearance_margin_s: float = 1.5
    approach_m: float = 60.0
    lookback_m: float = 100.0
    moving_mps: float = 0.5
    lateral_margin_m: float = 0.5
    heading_cos_min: float = 0.5
    zone_margin_m: float = 1.0
    lost_track_s: float = 10.0

    def __post_init__(self) -> None:
        for name in (
            "critical_gap_right_s",
            "critical_gap_through_s",
            "critical_gap_left_s",
            "clearance_accel_mps2",
            "clearance_lateral_accel_mps2",
            "approach_m",
            "lookback_m",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"GiveWayConfig.{name}: expected a positive number, got {value!r}")
        for name in ("clearance_margin_s", "moving_mps", "lateral_margin_m", "zone_margin_m", "lost_track_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"GiveWayConfig.{name}: expected a finite value >= 0, got {value!r}")
        if not -1.0 <= self.heading_cos_min <= 1.0:
            raise ConfigError(
                f"GiveWayConfig.heading_cos_min: expected a cosine in [-1, 1], got {self.heading_cos_min!r}"
            )

    def critical_gap_s(self, turn: str) -> float:
        """The HCM critical headway of the route's movement ("left", "right", else through)."""
        if turn == "right":
            return self.critical_gap_right_s
        if turn == "left":
            return self.critical_gap_left_s
        return self.critical_gap_through_s
