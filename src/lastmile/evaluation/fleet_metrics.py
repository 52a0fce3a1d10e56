"""Fleet metrics of a run with the dispatch server: requests made and served, wait and ride times,
vehicle utilisation and distance per passenger, all in simulated time."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.errors import ConfigError


@dataclass(frozen=True, slots=True, kw_only=True)
class RideRecord:
    """One rider's request as the run saw it; times are simulated seconds (None: not yet).

    Attributes:
        ref: the run's own id for the rider (the API's ``client_ref``).
        origin, destination: stop ids.
        seats: seats asked for.
        requested_s: when the request reached the server.
        picked_up_s, dropped_off_s: when the shuttle reported the pick-up / drop-off done.
        vehicle_id: the shuttle that served it ("" if none).
    """

    ref: str
    origin: str
    destination: str
    seats: int
    requested_s: float
    picked_up_s: float | None = None
    dropped_off_s: float | None = None
    vehicle_id: str = ""


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleRecord:
    """One shuttle's totals: distance driven, simulated time, and time with a rider on board."""

    vehicle_id: str
    distance_m: float
    duration_s: float
    occupied_s: float
    seat_s: float


def _stat(values: Sequence[float]) -> dict[str, float | None]:
    if not values:
        return {"median": None, "p95": None, "max": None}
    arr = np.asarray(values, dtype=float)
    return {
        "median": float(np.median(arr)),
        "p95": float(np.percentile(arr, 95)),
        "max": float(arr.max()),
    }


def compute_fleet_metrics(
    rides: Sequence[RideRecord], vehicles: Sequence[VehicleRecord], capacity_seats: int
) -> dict[str, Any]:
    """The fleet section of the report.

    Utilisation is the share of shuttle time with at least one rider on board; seat occupancy is
    seat-seconds used over seat-seconds offered. km per passenger is the fleet's distance over the
    riders delivered (None when nobody was delivered).
    """
    if capacity_seats <= 0:
        raise ConfigError(f"compute_fleet_metrics: expected capacity_seats > 0, got {capacity_seats}")
    served = [r for r in rides if r.dropped_off_s is not None]
    picked = [r for r in rides if r.picked_up_s is not None]
    waits = [r.picked_up_s - r.requested_s for r in picked if r.picked_up_s is not None]
    rides_s = [
        r.dropped_off_s - r.picked_up_s
        for r in served
        if r.dropped_off_s is not None and r.picked_up_s is not None
    ]
    distance_m = sum(v.distance_m for v in vehicles)
    time_s = sum(v.duration_s for v in vehicles)
    passengers = sum(r.seats for r in served)
    return {
        "shuttles": len(vehicles),
        "requests_made": len(rides),
        "requests_picked_up": len(picked),
        "requests_served": len(served),
        "passengers_delivered": passengers,
        "wait_s": _stat(waits),
        "ride_s": _stat(rides_s),
        "utilisation": sum(v.occupied_s for v in vehicles) / time_s if time_s > 0 else None,
        "seat_occupancy": sum(v.seat_s for v in vehicles) / (time_s * capacity_seats) if time_s > 0 else None,
        "fleet_distance_km": distance_m / 1e3,
        "km_per_passenger": distance_m / 1e3 / passengers if passengers else None,
        "per_vehicle": {
            v.vehicle_id: {
                "distance_km": v.distance_m / 1e3,
                "utilisation": v.occupied_s / v.duration_s if v.duration_s > 0 else None,
            }
            for v in vehicles
        },
    }


def write_fleet_report(metrics: dict[str, Any], rides: Sequence[RideRecord], run_dir: Path) -> Path:
    """``fleet_metrics.json``, ``fleet_rides.json`` and ``fleet_report.md`` in ``run_dir``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "fleet_metrics.json").write_text(json.dumps(metrics, indent=2, sort_keys=True))
    (run_dir / "fleet_rides.json").write_text(
        json.dumps([{f: getattr(r, f) for f in RideRecord.__slots__} for r in rides], indent=2)
    )

    def fmt(v: float | None, unit: str = "") -> str:
        return "–" if v is None else f"{v:.1f}{unit}"

    m = metrics
    lines = [
        "# Fleet run",
        "",
        f"{m['shuttles']} shuttles; times are simulated seconds.",
        "",
        "| metric | value |",
        "|---|---|",
        f"| requests made | {m['requests_made']} |",
        f"| requests picked up | {m['requests_picked_up']} |",
        f"| requests served (dropped off) | {m['requests_served']} |",
        f"| wait (request to pick-up) median / p95 | {fmt(m['wait_s']['median'], ' s')} / "
        f"{fmt(m['wait_s']['p95'], ' s')} |",
        f"| ride (pick-up to drop-off) median / p95 | {fmt(m['ride_s']['median'], ' s')} / "
        f"{fmt(m['ride_s']['p95'], ' s')} |",
        f"| utilisation (time with a rider on board) | {fmt(_pct(m['utilisation']), ' %')} |",
        f"| seat occupancy | {fmt(_pct(m['seat_occupancy']), ' %')} |",
        f"| fleet distance | {m['fleet_distance_km']:.2f} km |",
        f"| km per passenger | {fmt(m['km_per_passenger'])} |",
        "",
        "Each shuttle's own run (trace, events, report) is in `shuttle-<k>/`.",
        "",
    ]
    path = run_dir / "fleet_report.md"
    path.write_text("\n".join(lines))
    return path


def _pct(v: float | None) -> float | None:
    return None if v is None else 100.0 * v
