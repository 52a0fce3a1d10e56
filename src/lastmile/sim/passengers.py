"""Passengers: Poisson arrivals at stops, stop and seat buttons, boarding through a sensed door."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.run_events import EventKind
from lastmile.hdmap.model import BusStop


@dataclass(slots=True)
class Passenger:
    id: int
    origin: str
    destination: str
    arrived_s: float
    boarded_s: float | None = None
    alight_anywhere: bool = False
    """Pressed the drop-off button: gets off at the next door opening, at a stop or at the kerb."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PassengerConfig:
    """Demand at the stops.

    Attributes:
        arrivals_per_stop_per_min: Poisson rate of new riders at each stop.
        initial_waiting: riders already waiting at t = 0, by stop id.
        initial_waiting_per_stop: riders already waiting at t = 0 at every stop (a route's stops are
            named in its file, so a generic service cannot list them by id).
        board_s: time one rider takes through the door (boarding or alighting).
        door_s: time for the door to open or close fully.
    """

    arrivals_per_stop_per_min: float = 0.3
    initial_waiting: dict[str, int] = field(default_factory=dict)
    initial_waiting_per_stop: int = 0
    board_s: float = 2.5
    door_s: float = 2.0


@dataclass(slots=True)
class StopVisit:
    """An ongoing stop: when the door opened and who moved through it."""

    stop_id: str
    opened_s: float
    curb_gap_m: float
    body_gap_m: float
    longitudinal_error_m: float
    boarded: int = 0
    alighted: int = 0


class PassengerModel:
    """Riders at the stops and on board, and the door they move through."""

    def __init__(
        self,
        stops: tuple[BusStop, ...],
        config: PassengerConfig,
        rng: np.random.Generator,
        seats: int,
        drop_off_times_s: tuple[float, ...] = (),
    ) -> None:
        """Args:
        drop_off_times_s: one rider on board from the start per entry, who presses the drop-off
            button at that time (``Scenario.drop_off_requests``).
        """
        self.stops = {s.id: s for s in stops}
        self.order = [s.id for s in stops]
        self.config = config
        self.rng = rng
        self.seats = seats
        self.waiting: dict[str, list[Passenger]] = {s: [] for s in self.order}
        self.onboard: list[Passenger] = []
        self._next_id = 1
        self._next_arrival = {s: self._draw_gap() for s in self.order}
        self.new_calls: list[tuple[str, str]] = []
        self.door_position = 0.0  # 0 closed .. 1 open
        self._transfer_left_s = 0.0
        self.visit: StopVisit | None = None
        if len(self.order) < 2:
            raise ConfigError(f"passengers: expected a map with at least 2 stops, got {len(self.order)}")
        unknown = set(config.initial_waiting) - set(self.stops)
        if unknown:
            raise ConfigError(
                f"passengers.initial_waiting: expected stop ids {self.order}, got {sorted(unknown)}"
            )
        per_stop = config.initial_waiting_per_stop
        if per_stop < 0:
            raise ConfigError(f"passengers.initial_waiting_per_stop: expected 0 or more, got {per_stop}")
        for stop_id in self.order:
            for _ in range(per_stop):
                self._add(stop_id, 0.0)
        for stop_id, count in config.initial_waiting.items():
            for _ in range(count):
                self._add(stop_id, 0.0)
        if len(drop_off_times_s) > seats:
            raise ConfigError(
                f"drop_off_requests: expected at most {seats} riders on board (the seats), "
                f"got {len(drop_off_times_s)}"
            )
        self._presses: list[tuple[float, Passenger]] = []
        for t_s in sorted(drop_off_times_s):
            rider = Passenger(self._next_id, "", "", 0.0, boarded_s=0.0)
            self._next_id += 1
            self.onboard.append(rider)
            self._presses.append((t_s, rider))
        self._kerb_drop_offs = False
        """A drop-off rider has pressed and may get off away from a stop (or is getting off there)."""
        self.drop_off_alightings: list[tuple[int, str | None]] = []
        """(passenger id, stop id or None at the kerb) of drop-off riders who got off, for the referee."""

    def press_due(self, t_s: float) -> list[tuple[int, int]]:
        """The drop-off buttons pressed by ``t_s``: (passenger id, seat) of each; those riders now get
        off at the next door opening."""
        out = []
        while self._presses and self._presses[0][0] <= t_s:
            _, rider = self._presses.pop(0)
            rider.alight_anywhere = True
            self._kerb_drop_offs = True
            out.append((rider.id, self.onboard.index(rider)))
        return out

    def _draw_gap(self) -> float:
        rate = self.config.arrivals_per_stop_per_min / 60.0
        return float(self.rng.exponential(1.0 / rate)) if rate > 0 else math.inf

    def _add(self, stop_id: str, t_s: float) -> None:
        others = [s for s in self.order if s != stop_id]
        dest = others[int(self.rng.integers(len(others)))]
        if not self.waiting[stop_id]:
            self.new_calls.append((stop_id, "stop_button"))
        self.waiting[stop_id].append(Passenger(self._next_id, stop_id, dest, t_s))
        self._next_id += 1

    def step_arrivals(self, t_s: float) -> None:
        for stop_id in self.order:
            while self._next_arrival[stop_id] <= t_s:
                self._add(stop_id, self._next_arrival[stop_id])
                self._next_arrival[stop_id] += self._draw_gap()

    def step_door(
        self, t_s: float, dt_s: float, door_cmd_open: bool, at_stop: str | None, stopped: bool
    ) -> list[tuple[EventKind, dict[str, object]]]:
        """Move the door and the riders; returns events (kind, data) for the run log."""
        events: list[tuple[EventKind, dict[str, object]]] = []
        # The door interlock: it opens only at standstill.
        want_open = door_cmd_open and stopped
        rate = dt_s / self.config.door_s
        self.door_position = (
            min(1.0, self.door_position + rate) if want_open else max(0.0, self.door_position - rate)
        )
        if self.door_position >= 1.0 and at_stop is None and self._kerb_drop_offs:
            return self._alight_at_kerb(t_s, dt_s)
        if self.door_position < 1.0 or at_stop is None or self.visit is None:
            return events
        if self._transfer_left_s > 0.0:
            self._transfer_left_s -= dt_s
            return events
        visit = self.visit
        leaving = [p for p in self.onboard if p.destination == at_stop or p.alight_anywhere]
        if leaving:
            p = leaving[0]
            self.onboard.remove(p)
            if p.alight_anywhere:
                self.drop_off_alightings.append((p.id, at_stop))
            visit.alighted += 1
            self._transfer_left_s = self.config.board_s
            ride = t_s - (p.boarded_s or t_s)
            events.append(
                (
                    EventKind.PASSENGER_ALIGHTED,
                    {"passenger_id": p.id, "stop_id": at_stop, "ride_s": round(ride, 3)},
                )
            )
            return events
        queue = self.waiting[at_stop]
        if queue and len(self.onboard) < self.seats:
            p = queue.pop(0)
            p.boarded_s = t_s
            self.onboard.append(p)
            visit.boarded += 1
            self._transfer_left_s = self.config.board_s
            self.new_calls.append((p.destination, "seat_button"))
            events.append(
                (
                    EventKind.PASSENGER_BOARDED,
                    {"passenger_id": p.id, "stop_id": at_stop, "wait_s": round(t_s - p.arrived_s, 3)},
                )
            )
        return events

    def _alight_at_kerb(self, t_s: float, dt_s: float) -> list[tuple[EventKind, dict[str, object]]]:
        """The door open away from any stop: a rider who pressed the drop-off button gets off (one
        every ``board_s``); nobody else does."""
        if self._transfer_left_s > 0.0:
            self._transfer_left_s -= dt_s
            return []
        p = next((p for p in self.onboard if p.alight_anywhere), None)
        if p is None:
            self._kerb_drop_offs = False  # everyone who asked is off, and the last one is through
            return []
        self.onboard.remove(p)
        self.drop_off_alightings.append((p.id, None))
        self._transfer_left_s = self.config.board_s
        ride = round(t_s - (p.boarded_s or t_s), 3)
        return [(EventKind.PASSENGER_ALIGHTED, {"passenger_id": p.id, "stop_id": "", "ride_s": ride})]

    def end_visit(self) -> dict[str, object] | None:
        """Once the door has closed on a visit: the visit's ``stop_served`` event data, and the visit
        ends. ``left_waiting`` counts the riders still at the stop as the door closed (no seat free,
        or they arrived after the last one boarded); ``seats_free`` says which. None otherwise."""
        v = self.visit
        if v is None or self.door_position != 0.0:
            return None
        self.visit = None
        return {
            "stop_id": v.stop_id,
            "curb_gap_m": v.curb_gap_m,
            "body_gap_m": v.body_gap_m,
            "longitudinal_error_m": v.longitudinal_error_m,
            "boarded": v.boarded,
            "alighted": v.alighted,
            "left_waiting": len(self.waiting[v.stop_id]),
            "seats_free": self.seats - len(self.onboard),
        }

    @property
    def person_in_doorway(self) -> bool:
        return self._transfer_left_s > 0.0

    def wants_stop(self, stop_id: str) -> bool:
        return bool(self.waiting[stop_id]) or any(p.destination == stop_id for p in self.onboard)
