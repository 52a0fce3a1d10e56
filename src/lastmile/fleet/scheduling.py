"""Where the shuttles go: the fixed loop, the timetable of Snow Lion's Table 1, and insertion of rides.

The shuttle drives one fixed loop (S1 -> S2 -> S3 -> S4 -> S1). A vehicle's plan is an ordered list of
stop visits ahead of it; each visit carries the pick-ups, drop-offs, timetable calls and seat-button
stops to do there. On the loop a visit's place is its distance ahead of the vehicle "unrolled" over
laps, so inserting a ride means choosing the lap on which to pick the rider up; the drop-off is then the
first pass of the destination after the pick-up. Every candidate is checked against the seats on board
along the whole ride, and the cheapest (rider's pick-up time plus the delay it adds to riders already
planned) wins. This is the classic insertion heuristic restricted to the order the route allows.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from lastmile.core.errors import ConfigError, RoutingError
from lastmile.core.polyline import Polyline
from lastmile.hdmap.service_route import ServiceRoute

CAPACITY_SEATS = 6  # Snow Lion carries up to six passengers
# Table 1 of Snow Lion: three two-hour shifts a day (morning, noon, evening), 20-minute headway.
SHIFTS = (
    ("morning", 8 * 3600, 10 * 3600),
    ("noon", 12 * 3600, 14 * 3600),
    ("evening", 17 * 3600 + 1800, 19 * 3600),
)


@dataclass(frozen=True, slots=True, kw_only=True)
class SchedulingConfig:
    """Parameters of the service model.

    Attributes:
        cruise_mps: mean speed along the loop used for estimates (Snow Lion: max 15 km/h).
        dwell_s: time spent at a stop that has work to do (Snow Lion waits ~8 s after halting, plus
            boarding).
        horizon_laps: how many laps ahead a ride may be planned; beyond it the ride waits in the queue.
        at_stop_tolerance_m: a vehicle this close past a stop is still at it (it is dwelling in the bay).
        comfort_decel_mps2: deceleration used to decide which stop the seat button can still reach.
        headway_s: timetable departures from S1 this often inside each shift.
        delay_weight: weight of the delay added to already-planned riders in the insertion cost.
    """

    cruise_mps: float = 3.0
    dwell_s: float = 20.0
    horizon_laps: int = 2
    at_stop_tolerance_m: float = 15.0
    comfort_decel_mps2: float = 1.0
    headway_s: float = 1200.0
    delay_weight: float = 1.0

    def __post_init__(self) -> None:
        for name in ("cruise_mps", "dwell_s", "at_stop_tolerance_m", "comfort_decel_mps2", "headway_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"SchedulingConfig.{name}: expected a positive number, got {value!r}")
        if self.horizon_laps < 1:
            raise ConfigError(f"SchedulingConfig.horizon_laps: expected >= 1, got {self.horizon_laps}")


@dataclass(frozen=True, slots=True, kw_only=True)
class StopInfo:
    """A stop of the loop: ``route_s_m`` is its arc length along the loop from the loop's start."""

    id: str
    name: str
    x_m: float
    y_m: float
    route_s_m: float


FLEET_STOP_ID = re.compile(r"^[A-Za-z0-9_-]{1,16}$")
"""What the dispatch API, its database and its dashboard take as a stop id (``api_models.StopId``)."""


def fleet_stop_ids(service: ServiceRoute) -> dict[str, str]:
    """The dispatch id of each of the service's stops, by its id in the map (``BusStop.id``).

    A map id the API can carry is kept (the campus's S1-S4, "K-Block"); a stop named in words by a
    route file ("Roundabout West", "Library (return)") becomes ``S<k>``, k its place in service order,
    so riders, operators and the database see a short safe id while the name is still shown.
    """
    names = [stop.name for stop in service.stops]
    kept = {name for name in names if FLEET_STOP_ID.match(name)}
    ids: dict[str, str] = {}
    for k, name in enumerate(names, start=1):
        if name in kept:
            ids[name] = name
            continue
        fleet_id, suffix = f"S{k}", 0
        while fleet_id in kept or fleet_id in ids.values():  # a kept map id may itself be S<k>
            suffix += 1
            fleet_id = f"S{k}_{suffix}"
        ids[name] = fleet_id
    return ids


class LoopRoute:
    """A service's loop as a closed polyline with its stops in driving order (the campus loop, or the
    loop of a route file: see ``hdmap.service_route``)."""

    def __init__(self, service: ServiceRoute) -> None:
        self.polyline: Polyline = service.polyline
        self.length_m = self.polyline.length_m
        names = {bay.id: bay.name for bay in service.hdmap.stops}
        self.fleet_ids = fleet_stop_ids(service)
        stops = [
            StopInfo(
                id=self.fleet_ids[stop.name],
                name=names.get(stop.name, stop.name),
                x_m=stop.x_m,
                y_m=stop.y_m,
                route_s_m=stop.route_s_m,
            )
            for stop in service.stops
        ]
        if not stops:
            raise RoutingError(f"LoopRoute: expected stops on service {service.name!r}, got none")
        stops.sort(key=lambda s: s.route_s_m)
        self.stops: dict[str, StopInfo] = {s.id: s for s in stops}
        self.order: tuple[str, ...] = tuple(s.id for s in stops)

    def ahead_m(self, from_s_m: float, to_s_m: float) -> float:
        """Distance driven forward along the loop from one arc length to another, in [0, length)."""
        return (to_s_m - from_s_m) % self.length_m

    def stop_ahead_m(self, from_stop: str, to_stop: str) -> float:
        """Forward distance between two stops; a full lap between two visits of the same stop."""
        d = self.ahead_m(self.stops[from_stop].route_s_m, self.stops[to_stop].route_s_m)
        return d if d > 0 else self.length_m

    def project_s(self, x_m: float, y_m: float, hint_s_m: float | None = None) -> float:
        return self.polyline.project(x_m, y_m, hint_s_m=hint_s_m, window_m=60.0).s_m


@dataclass(slots=True, kw_only=True)
class PlanItem:
    """One task at a stop. ``kind`` is pickup, dropoff, timetable or seat_stop; ``seats`` boards (+)
    at a pickup and alights at a dropoff."""

    trip_id: int
    kind: str
    request_id: str | None = None
    seats: int = 0
    run_id: str | None = None


@dataclass(slots=True, kw_only=True)
class Visit:
    stop_id: str
    items: list[PlanItem] = field(default_factory=list)

    def net_seats(self) -> int:
        return sum(
            (i.seats if i.kind == "pickup" else -i.seats if i.kind == "dropoff" else 0) for i in self.items
        )

    def riders(self) -> int:
        return sum(1 for i in self.items if i.kind in ("pickup", "dropoff"))


@dataclass(frozen=True, slots=True, kw_only=True)
class Insertion:
    """Where a ride goes in a plan: ``pickup_at_m`` / ``dropoff_at_m`` are unrolled distances ahead."""

    vehicle_id: str
    pickup_at_m: float
    dropoff_at_m: float
    eta_pickup_s: float
    eta_dropoff_s: float
    cost_s: float


class Planner:
    """Pure planning functions over a ``LoopRoute``; the dispatcher owns the plans."""

    def __init__(self, route: LoopRoute, config: SchedulingConfig | None = None) -> None:
        self.route = route
        self.config = config or SchedulingConfig()
        self._memo: dict[str, tuple[list[Visit], float, int, list[float], list[int]]] = {}

    def origin_s_m(self, vehicle_s_m: float) -> float:
        """Where every distance ahead is measured from: the stop the vehicle is dwelling at, when it is
        less than ``at_stop_tolerance_m`` past it (in its bay), else the vehicle's own position.

        One origin for every stop matters: measured from the vehicle, the stop it dwells at would be
        0 ahead now but a lap minus the overshoot ahead next time round, while plans add whole
        stop-to-stop distances; a ride placed on that next pass then landed a visit out of order (found
        by the property test of ``best_insertion``: a drop-off planned before its pick-up).
        """
        for stop in self.route.stops.values():
            if self.route.ahead_m(stop.route_s_m, vehicle_s_m) < self.config.at_stop_tolerance_m:
                return stop.route_s_m
        return vehicle_s_m

    def first_ahead_m(self, vehicle_s_m: float, stop_id: str) -> float:
        """Distance to the next pass of ``stop_id``; 0 if the vehicle is at (or just past) it."""
        return self.route.ahead_m(self.origin_s_m(vehicle_s_m), self.route.stops[stop_id].route_s_m)

    def unrolled_m(self, plan: list[Visit], vehicle_s_m: float) -> list[float]:
        """Distance ahead of the vehicle to each visit, increasing along the plan."""
        out: list[float] = []
        for k, visit in enumerate(plan):
            if k == 0:
                out.append(self.first_ahead_m(vehicle_s_m, visit.stop_id))
            else:
                out.append(out[-1] + self.route.stop_ahead_m(plan[k - 1].stop_id, visit.stop_id))
        return out

    def time_to_s(self, at_m: float, visits_before: int) -> float:
        return at_m / self.config.cruise_mps + visits_before * self.config.dwell_s

    def eta_s(self, plan: list[Visit], vehicle_s_m: float, trip_id: int) -> float | None:
        """Seconds until the vehicle does ``trip_id`` along its plan, or None if it is not planned."""
        for k, (visit, d) in enumerate(zip(plan, self.unrolled_m(plan, vehicle_s_m), strict=True)):
            if any(i.trip_id == trip_id for i in visit.items):
                return self.time_to_s(d, k)
        return None

    def _profile(
        self, vehicle_id: str, plan: list[Visit], vehicle_s_m: float, onboard: int
    ) -> tuple[list[float], list[int]]:
        """Distances ahead and seats taken after each visit; memoised per vehicle because a busy
        server asks about the same unchanged plan for every queued ride (plans are replaced, never
        edited, when they change, so the list's identity is the key)."""
        hit = self._memo.get(vehicle_id)
        if hit is not None and hit[0] is plan and hit[1] == vehicle_s_m and hit[2] == onboard:
            return hit[3], hit[4]
        ds = self.unrolled_m(plan, vehicle_s_m)
        load_after: list[int] = []
        load = onboard  # seats taken now, as the vehicle reports them
        for visit in plan:
            load += visit.net_seats()
            load_after.append(load)
        self._memo[vehicle_id] = (plan, vehicle_s_m, onboard, ds, load_after)
        return ds, load_after

    def best_insertion(
        self,
        vehicle_id: str,
        plan: list[Visit],
        vehicle_s_m: float,
        onboard: int,
        capacity: int,
        origin: str,
        destination: str,
        seats: int,
    ) -> Insertion | None:
        """The cheapest feasible place for a ride in one vehicle's plan, or None within the horizon."""
        cfg, route = self.config, self.route
        ds, load_after = self._profile(vehicle_id, plan, vehicle_s_m, onboard)
        ride_m = route.stop_ahead_m(origin, destination)
        first = self.first_ahead_m(vehicle_s_m, origin)
        for lap in range(cfg.horizon_laps):
            p = first + lap * route.length_m
            q = p + ride_m
            if ds and p > ds[-1] + route.length_m:
                break  # beyond the plan plus one lap nothing changes but the wait grows
            if _peak_load(ds, load_after, onboard, p, q) + seats > capacity:
                continue
            merged_p, merged_q = _visit_at(ds, p) is not None, _visit_at(ds, q) is not None
            before_p = sum(1 for d in ds if d < p - _SAME_M)
            before_q = sum(1 for d in ds if d < q - _SAME_M) + (0 if merged_p else 1)
            eta_p = self.time_to_s(p, before_p)
            eta_q = self.time_to_s(q, before_q)
            added_s = _added_wait_s(plan, ds, (p, merged_p), (q, merged_q), cfg.dwell_s)
            # The first feasible lap is the cheapest: later laps only add a full loop of waiting.
            return Insertion(
                vehicle_id=vehicle_id,
                pickup_at_m=p,
                dropoff_at_m=q,
                eta_pickup_s=eta_p,
                eta_dropoff_s=eta_q,
                cost_s=eta_p + (eta_q - eta_p) + cfg.delay_weight * added_s,
            )
        return None

    def insert(
        self, plan: list[Visit], vehicle_s_m: float, at_m: float, stop_id: str, item: PlanItem
    ) -> list[Visit]:
        """Put ``item`` in the visit ``at_m`` ahead (merging with a visit already there); a new plan."""
        ds = self.unrolled_m(plan, vehicle_s_m)
        new = [Visit(stop_id=v.stop_id, items=list(v.items)) for v in plan]
        for k, d in enumerate(ds):
            if abs(d - at_m) < 1e-6:
                new[k].items.append(item)
                return new
        k = sum(1 for d in ds if d < at_m)
        new.insert(k, Visit(stop_id=stop_id, items=[item]))
        return new

    def seat_button_stop(self, vehicle_s_m: float, speed_mps: float) -> tuple[str, float]:
        """The next stop the vehicle can still reach with a comfortable stop: (stop id, metres ahead)."""
        cfg = self.config
        need = speed_mps**2 / (2 * cfg.comfort_decel_mps2) + 5.0
        best: tuple[str, float] | None = None
        for stop_id in self.route.order:
            d = self.route.ahead_m(vehicle_s_m, self.route.stops[stop_id].route_s_m)
            if d < need:
                d += self.route.length_m
            if best is None or d < best[1]:
                best = (stop_id, d)
        assert best is not None
        return best


_SAME_M = 1e-6
"""Two unrolled distances this close are the same visit."""


def _visit_at(ds: list[float], at_m: float) -> int | None:
    """The index of the planned visit at ``at_m`` ahead, if there is one."""
    return next((k for k, d in enumerate(ds) if abs(d - at_m) < _SAME_M), None)


def _peak_load(ds: list[float], load_after: list[int], onboard: int, p: float, q: float) -> int:
    """The most seats taken between a pick-up ``p`` and a drop-off ``q`` metres ahead."""
    at_p = _visit_at(ds, p)
    if at_p is not None:
        peak = load_after[at_p]
    else:
        before_p = sum(1 for d in ds if d < p - _SAME_M)
        peak = load_after[before_p - 1] if before_p else onboard
    for k, d in enumerate(ds):
        if p + _SAME_M < d < q - _SAME_M:
            peak = max(peak, load_after[k])
    return peak


def _added_wait_s(
    plan: list[Visit],
    ds: list[float],
    pickup: tuple[float, bool],
    dropoff: tuple[float, bool],
    dwell_s: float,
) -> float:
    """Each new visit (one not merged with a planned one) makes every rider planned after it wait one
    more dwell; ``pickup`` and ``dropoff`` are (metres ahead, merged)."""
    added = 0.0
    for k, d in enumerate(ds):
        riders = plan[k].riders()
        for at_m, merged in (pickup, dropoff):
            if not merged and d > at_m + _SAME_M:
                added += riders * dwell_s
    return added


@dataclass(frozen=True, slots=True, kw_only=True)
class TimetableEntry:
    """One call of a timetable run at a stop, ``time_s`` seconds after midnight (service day)."""

    run_id: str
    shift: str
    seq: int
    stop_id: str
    time_s: float


def build_timetable(route: LoopRoute, config: SchedulingConfig | None = None) -> list[TimetableEntry]:
    """Snow Lion's Table 1 on our loop: departures from the first stop every headway within each shift,
    each calling at every stop once around the loop, times from distance / cruise speed plus dwell."""
    cfg = config or SchedulingConfig()
    first = route.order[0]
    out: list[TimetableEntry] = []
    for shift, start_s, end_s in SHIFTS:
        depart = float(start_s)
        while depart < end_s:
            run_id = f"{shift}-{int(depart) // 3600:02d}{int(depart) % 3600 // 60:02d}"
            t = depart
            prev = first
            for seq, stop_id in enumerate([*route.order, first]):
                if seq > 0:
                    t += route.stop_ahead_m(prev, stop_id) / cfg.cruise_mps + cfg.dwell_s
                out.append(TimetableEntry(run_id=run_id, shift=shift, seq=seq, stop_id=stop_id, time_s=t))
                prev = stop_id
            depart += cfg.headway_s
    return out


def due_runs(first_calls_s: dict[str, float], now_s: float, lead_s: float) -> list[str]:
    """Timetable runs to hand out now: those departing within ``lead_s`` from ``now_s`` (both seconds
    after midnight of the service day), soonest first. A run whose departure has passed is not due."""
    due = [(t, run_id) for run_id, t in first_calls_s.items() if now_s <= t <= now_s + lead_s]
    return [run_id for _, run_id in sorted(due)]
