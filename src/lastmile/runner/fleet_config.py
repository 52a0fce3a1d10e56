"""What a fleet run is: its configuration, and the riders' demand (a Poisson process per stop pair)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.fleet.scheduling import CAPACITY_SEATS
from lastmile.runner.run_config import BASE_TICK_US as TICK_US


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetConfig:
    """A fleet run.

    Attributes:
        shuttles: how many shuttles, >= 1; spaced evenly round the loop at the start.
        minutes: longest simulated duration.
        seed: the root seed; each shuttle's simulator and the demand model get their own stream.
        demand_per_pair_per_h: Poisson rate of ride requests per ordered stop pair (riders per hour).
        demand_minutes: riders arrive during the first this-many simulated minutes (None: all run).
        until_served: end early once the demand window is over and every request has been dropped off.
        sync_period_s: simulated seconds between exchanges with the server.
        cruise_speed_mps: the shuttles' cruise speed (None: the stack's default, 20 km/h).
        max_seats: each request asks for 1..max_seats seats (uniform).
        pedestrian_mean_gap_s: pedestrians cross at every crosswalk on the loop, this many seconds
            apart on average, in the world all shuttles share (None: no pedestrians).
        cameras: a crossing camera (NUS) at every crosswalk on the loop reports presence through the
            server to the shuttles.
        camera_rate_hz: the cameras' capture rate (NUS: 5 Hz, and 1 Hz).
        camera_keepalive_s: a camera posts a report when presence changes, and at least this often.
        route: a route file (TOML) whose loop and stops the fleet serves; "" for the campus loop.
    """

    shuttles: int = 2
    minutes: float = 10.0
    seed: int = 0
    demand_per_pair_per_h: float = 2.0
    demand_minutes: float | None = None
    until_served: bool = False
    sync_period_s: float = 1.0
    cruise_speed_mps: float | None = None
    max_seats: int = 2
    pedestrian_mean_gap_s: float | None = 40.0
    cameras: bool = True
    camera_rate_hz: float = 5.0
    camera_keepalive_s: float = 1.0
    route: str = ""

    def __post_init__(self) -> None:
        if self.shuttles < 1:
            raise ConfigError(f"fleet: expected at least 1 shuttle, got {self.shuttles}")
        if self.seed < 0:
            raise ConfigError(f"fleet seed: expected a non-negative integer, got {self.seed}")
        if not self.minutes > 0:
            raise ConfigError(f"fleet minutes: expected > 0, got {self.minutes}")
        if self.demand_per_pair_per_h < 0:
            raise ConfigError(f"fleet demand_per_pair_per_h: expected >= 0, got {self.demand_per_pair_per_h}")
        if not self.sync_period_s > 0 or round(self.sync_period_s * 1e6) % TICK_US:
            raise ConfigError(
                f"fleet sync_period_s: expected a positive multiple of {TICK_US / 1e6} s, "
                f"got {self.sync_period_s}"
            )
        if self.pedestrian_mean_gap_s is not None and not self.pedestrian_mean_gap_s > 0:
            raise ConfigError(
                f"fleet pedestrian_mean_gap_s: expected > 0 or None, got {self.pedestrian_mean_gap_s}"
            )
        if not self.camera_keepalive_s > 0:
            raise ConfigError(f"fleet camera_keepalive_s: expected > 0, got {self.camera_keepalive_s}")
        if not 1 <= self.max_seats <= CAPACITY_SEATS:
            raise ConfigError(f"fleet max_seats: expected 1..{CAPACITY_SEATS}, got {self.max_seats}")


@dataclass(frozen=True, slots=True)
class Demand:
    """One rider: when they ask, from where to where, how many seats."""

    t_s: float
    origin: str
    destination: str
    seats: int


def poisson_demand(
    stop_ids: list[str], rate_per_pair_per_h: float, window_s: float, max_seats: int, rng: np.random.Generator
) -> list[Demand]:
    """Riders for every ordered stop pair as independent Poisson processes over ``[0, window_s)``."""
    out: list[Demand] = []
    rate_s = rate_per_pair_per_h / 3600.0
    for o in stop_ids:
        for d in stop_ids:
            if o == d or rate_s <= 0:
                continue
            n = int(rng.poisson(rate_s * window_s))
            times = np.sort(rng.uniform(0.0, window_s, size=n))
            seats = rng.integers(1, max_seats + 1, size=n)
            out.extend(Demand(float(t), o, d, int(k)) for t, k in zip(times, seats, strict=True))
    return sorted(out, key=lambda r: (r.t_s, r.origin, r.destination))
