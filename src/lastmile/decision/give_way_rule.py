"""Give-way lines and gap acceptance at two-way stops (issue #20).

aUToronto's "traffic-rule virtual lines" and Snow Lion's observation of unprotected intersections, with
the gap a driver would accept (HCM). At a yield line on the route (``hdmap.give_way_zones``: a
``right_of_way`` rule's give-way line, or a two-way stop's line once its full stop has been stood), the
shuttle crosses only when no tracked road user on the lanelets with priority would reach the conflict
zone (where the route's lanelet through the junction overlaps theirs) within the gap it needs: the
larger of the HCM critical headway of its movement and the time it needs to clear the zone plus a
margin (``GiveWayConfig``). Otherwise its front stops ``stop_before_line_m`` before the line and waits
until a gap opens.

A road user seen late (a radar track confirmed when the shuttle can no longer stop comfortably at the
line, ``traffic_light_rule.comfortable_stop_m``) is still given way to if the shuttle can stop
comfortably short of the conflict zone (``zone_margin_m`` before it: over the line, out of the other
lane's way). Once it cannot do that either, it is committed: a road user appearing then is the in-path
and cut-in rules' (a late hard stop would leave it standing in the other lane). At a two-way stop the
stop-sign rule holds the shuttle for its full stop first; the gap check then holds it at the same point.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.curve_speed import curvature_speed_limit_mps
from lastmile.core.objects import TrackedObjects
from lastmile.core.vehicle import VehicleGeometry
from lastmile.decision.gap_acceptance import Arrival, arrival_on, clearance_time_s
from lastmile.decision.give_way_config import GiveWayConfig
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig, comfortable_stop_m
from lastmile.hdmap.give_way_zones import YieldJunction, YieldKind, yield_junctions
from lastmile.hdmap.layers import SLayerDatabase

CURVE_SAMPLE_M = 1.0
"""The route's curvature through a junction is read every this many metres."""


@dataclass(frozen=True, slots=True)
class GiveWayVerdict:
    """The rule's answer for one cycle.

    Attributes:
        stop_front_s_m: where the front must stop (None: it may go).
        why: the reason, naming the rule and what it waits for.
        track_id: the road user arriving first that it waits for (-1: none).
        conflicts: how many road users it waits for.
    """

    stop_front_s_m: float | None
    why: str
    track_id: int = -1
    conflicts: int = 0


@dataclass
class GiveWayRule:
    """Stop points at the route's yield lines while priority traffic leaves no acceptable gap."""

    layers: SLayerDatabase
    geometry: VehicleGeometry
    config: GiveWayConfig = field(default_factory=GiveWayConfig)
    lines: TrafficLightRuleConfig = field(default_factory=TrafficLightRuleConfig)
    junctions: tuple[YieldJunction, ...] = ()
    _top_speed_mps: dict[int, float] = field(default_factory=dict)
    _committed: int | None = None
    _seen: dict[tuple[int, int], tuple[float, Arrival]] = field(default_factory=dict)
    """(zone, track) -> (when, its arrival then) of road users seen on an approach (``lost_track_s``)."""

    def __post_init__(self) -> None:
        if not self.config.enabled:
            return
        self.junctions = yield_junctions(
            self.layers.hdmap,
            self.layers.centerline,
            [(rl.stop_line, rl.s_m) for rl in self.layers.stop_lines],
            self.config.lookback_m,
        )
        for j in self.junctions:
            self._top_speed_mps[j.stop_line.id] = self._top_speed(j)

    def _top_speed(self, j: YieldJunction) -> float:
        """The speed the shuttle may reach through the junction: the route's limit and its curvature."""
        end = max((z.end_after_line_m for z in j.zones), default=0.0) + self.geometry.length_m
        s = j.line_s_m + np.arange(0.0, end + CURVE_SAMPLE_M, CURVE_SAMPLE_M)
        route = self.layers.centerline
        curvature = np.array([route.curvature_at(float(x)) for x in s])
        limit = float(np.min(self.layers.speed_limit_mps[self.layers.record_indices(s)]))
        curve = curvature_speed_limit_mps(curvature, self.config.clearance_lateral_accel_mps2)
        return min(limit, float(np.min(curve, initial=math.inf)))

    def step(
        self,
        t_s: float,
        front_s_m: float,
        speed_mps: float,
        cruise_mps: float,
        tracks: TrackedObjects,
        ahead: Callable[[float, float], float],
    ) -> GiveWayVerdict:
        """The verdict for the nearest yield line ahead.

        Args:
            cruise_mps: the shuttle's speed cap this cycle (the clearance never assumes more).
            ahead: route distance from the front to an s (wrapping on a loop), as the FSM measures it.
        """
        c = self.config
        best: tuple[float, YieldJunction] | None = None
        for j in self.junctions:
            d = ahead(j.line_s_m, front_s_m)
            behind = max(self._hold_after_line_m(j), self.lines.stop_before_line_m)
            if -behind < d < c.approach_m and (best is None or d < best[0]):
                best = (d, j)
        if best is None:
            self._committed = None
            self._seen.clear()
            return GiveWayVerdict(None, "")
        dist, j = best
        line_id = j.stop_line.id
        place = j.name or f"stop line {line_id}"
        if self._committed == line_id:
            return GiveWayVerdict(None, f"give way at {place}: committed")
        waits, need = self._conflicts(t_s, j, dist, speed_mps, cruise_mps, tracks)
        stop_s = self._stop_point(j, dist, speed_mps)
        if stop_s is None:
            # It can no longer stop short of the conflict zone: through it goes, whatever is seen now
            # (the in-path and cut-in rules still stop it for what enters its path).
            self._committed = line_id
            return GiveWayVerdict(None, f"give way at {place}: committed")
        if not waits:
            return GiveWayVerdict(None, f"give way at {place}: gap")
        first = min(waits, key=lambda a: a.time_s)
        count = len({a.track_id for a in waits})
        prefix = f"stop sign {line_id}: " if j.kind is YieldKind.STOP_SIGN else ""
        where = "" if stop_s <= j.line_s_m else ", short of the conflict zone"
        why = (
            f"{prefix}give way to {count} road user{'s' if count > 1 else ''} at {place}{where} "
            f"(first in {first.time_s:.1f} s, gap needed {need:.1f} s)"
        )
        return GiveWayVerdict(stop_s, why, first.track_id, count)

    def _hold_after_line_m(self, j: YieldJunction) -> float:
        """How far past the line the front may still stand, ``zone_margin_m`` short of the first zone
        (negative: the zone begins at the line)."""
        first = min((z.start_after_line_m for z in j.zones), default=0.0)
        return first - self.config.zone_margin_m

    def _stop_point(self, j: YieldJunction, dist_m: float, speed_mps: float) -> float | None:
        """Where the front would stop for priority traffic: ``stop_before_line_m`` before the line when
        it can still stop there comfortably, else short of the conflict zone when it can stop there,
        else None (committed)."""
        lines = self.lines
        need = comfortable_stop_m(speed_mps, lines) if speed_mps > self.config.moving_mps else 0.0
        at_line = dist_m - lines.stop_before_line_m
        if need <= max(at_line, lines.gap_floor_m):
            return j.line_s_m - lines.stop_before_line_m
        hold = self._hold_after_line_m(j)
        if hold > -lines.stop_before_line_m and need <= max(dist_m + hold, lines.gap_floor_m):
            return j.line_s_m + hold
        return None

    def _conflicts(
        self,
        t_s: float,
        j: YieldJunction,
        dist_m: float,
        speed_mps: float,
        cruise_mps: float,
        tracks: TrackedObjects,
    ) -> tuple[list[Arrival], float]:
        """The road users that would reach a conflict zone within the gap the shuttle needs for it,
        and the longest gap needed (for the reason)."""
        c, g = self.config, self.geometry
        top = min(cruise_mps, self._top_speed_mps[j.stop_line.id])
        # A two-way stop is crossed from rest at the line, whatever the speed now.
        v0 = 0.0 if j.kind is YieldKind.STOP_SIGN else speed_mps
        start = max(dist_m - self.lines.stop_before_line_m, 0.0) if j.kind is YieldKind.STOP_SIGN else 0.0
        waits: list[Arrival] = []
        need_max = 0.0
        present = {int(i) for i in tracks.ids}
        for k, zone in enumerate(j.zones):
            to_clear = dist_m - start + zone.end_after_line_m + g.length_m
            clear_s = clearance_time_s(to_clear, v0, c.clearance_accel_mps2, top)
            need = max(c.critical_gap_s(j.turn), clear_s + c.clearance_margin_s)
            need_max = max(need_max, need)
            arrivals = [a for approach in zone.approaches for a in arrival_on(tracks, approach, c)]
            arrivals += self._lost(t_s, k, arrivals, present)
            waits += [a for a in arrivals if a.time_s < need]
        return waits, need_max

    def _lost(self, t_s: float, zone: int, arrivals: list[Arrival], present: set[int]) -> list[Arrival]:
        """Road users seen on the zone's approaches whose tracks have since been lost (out of the
        radar's field of view as the shuttle turns towards the line), moved on at their last speed
        until they would have left the zone, for at most ``lost_track_s``."""
        for a in arrivals:
            self._seen[(zone, a.track_id)] = (t_s, a)
        out = []
        for (z, tid), (seen_s, a) in list(self._seen.items()):
            if z != zone or tid in present:
                if z == zone and all(b.track_id != tid for b in arrivals):
                    del self._seen[(z, tid)]  # still tracked, no longer on the approach
                continue
            gone_s = t_s - seen_s
            if gone_s > self.config.lost_track_s or a.leave_s - gone_s <= 0.0:
                del self._seen[(z, tid)]
                continue
            out.append(Arrival(tid, max(a.time_s - gone_s, 0.0), a.leave_s - gone_s))
        return out
