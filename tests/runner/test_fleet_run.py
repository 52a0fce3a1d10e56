"""``lastmile run --fleet N --serve`` end to end: simulated shuttles with their own stacks, linked to the
real dispatch server process over their WebSocket clients, serve every ride the demand model asks for,
and crossing cameras' reports reach their stacks through the server."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.evaluation.fleet_metrics import RideRecord, VehicleRecord, compute_fleet_metrics
from lastmile.runner.fleet_config import FleetConfig, poisson_demand
from lastmile.runner.fleet_run import run_fleet


def test_two_simulated_shuttles_serve_every_ride_through_the_real_server(tmp_path: Path) -> None:
    # Seed 15's demand in the first 20 s: S2 -> S3 and S1 -> S2 (two riders); the run ends once both
    # are dropped off, or fails at the 8-minute limit.
    config = FleetConfig(
        shuttles=2,
        minutes=8.0,
        seed=15,
        demand_per_pair_per_h=60.0,
        demand_minutes=20 / 60,
        until_served=True,
    )
    metrics = run_fleet(config, tmp_path)
    assert metrics["requests_made"] == 2
    assert metrics["requests_served"] == metrics["requests_made"]
    assert metrics["duration_s"] < 8 * 60  # ended because everything was served, not at the limit
    assert metrics["wait_s"]["median"] > 0 and metrics["ride_s"]["median"] > 0
    assert 0 < metrics["utilisation"] <= 1
    assert metrics["km_per_passenger"] > 0
    assert all(v["collisions"] == 0 for v in metrics["per_vehicle"].values())
    assert all(0 < v["max_seats_on_board"] <= 6 for v in metrics["per_vehicle"].values() if v["stops_served"])
    assert all(v["rule_violations"] == 0 for v in metrics["per_vehicle"].values())
    # Crossing cameras reported through the server to both shuttles' stacks, and a shuttle slowed for a
    # crossing they reported occupied (seed 15: once).
    infra = metrics["infrastructure"]
    assert infra["cameras"] == 3 and infra["reports_posted"] > 0
    assert infra["reports_delivered"] == 2 * infra["reports_posted"]
    assert set(infra["reports_received_by_stacks"].values()) == {infra["reports_posted"]}
    assert sum(v["v2i_anticipations"] for v in metrics["per_vehicle"].values()) >= 1
    rides = json.loads((tmp_path / "fleet_rides.json").read_text())
    assert all(r["requested_s"] < r["picked_up_s"] < r["dropped_off_s"] for r in rides)
    # The server's database agrees: both rides dropped off, by the vehicles the run says served them.
    import sqlalchemy as sa

    engine = sa.create_engine(f"sqlite:///{tmp_path / 'server' / 'fleet.db'}")
    with engine.connect() as conn:
        rows = conn.execute(sa.text("SELECT client_ref, state, vehicle_id FROM ride_requests")).all()
    engine.dispose()
    assert sorted((r[0], r[1], r[2]) for r in rows) == sorted(
        (r["ref"], "dropped_off", r["vehicle_id"]) for r in rides
    )
    # Each shuttle's own run directory, with the trips it reported done in its event log.
    done = []
    for k in range(2):
        log = json.loads((tmp_path / f"shuttle-{k}" / "run_log.json").read_text())
        done += [e for e in log["events"] if e["kind"] == "fleet_trip_done"]
    assert sorted(e["data"]["trip_kind"] for e in done) == ["dropoff", "dropoff", "pickup", "pickup"]
    # The stacks announced the stops on their HMI (logged per screen with the light and the cue).
    cues = set()
    for k in range(2):
        log = json.loads((tmp_path / f"shuttle-{k}" / "run_log.json").read_text())
        cues |= {e["data"]["cue"] for e in log["events"] if e["kind"] == "hmi"}
    assert {"driving", "pulling_over", "doors_open", "departing"} <= cues
    assert (tmp_path / "fleet_report.md").read_text().count("requests served") == 1


def test_poisson_demand_repeats_per_seed_and_has_the_asked_rate() -> None:
    stops = ["S1", "S2", "S3", "S4"]
    a = poisson_demand(stops, 30.0, 3600.0 * 20, 2, np.random.default_rng(3))
    b = poisson_demand(stops, 30.0, 3600.0 * 20, 2, np.random.default_rng(3))
    assert a == b
    # 12 ordered pairs x 30 / h x 20 h = 7,200 expected; Poisson sd ~85.
    assert abs(len(a) - 7200) < 5 * 85
    assert all(r.origin != r.destination and 1 <= r.seats <= 2 for r in a)
    assert [r.t_s for r in a] == sorted(r.t_s for r in a)


def test_fleet_metrics_medians_utilisation_and_km_per_passenger() -> None:
    rides = [
        RideRecord(
            ref="a",
            origin="S1",
            destination="S2",
            seats=2,
            requested_s=0.0,
            picked_up_s=10.0,
            dropped_off_s=40.0,
        ),
        RideRecord(
            ref="b",
            origin="S2",
            destination="S3",
            seats=1,
            requested_s=5.0,
            picked_up_s=35.0,
            dropped_off_s=45.0,
        ),
        RideRecord(ref="c", origin="S3", destination="S4", seats=1, requested_s=50.0),
    ]
    vehicles = [
        VehicleRecord(vehicle_id="v", distance_m=3000.0, duration_s=100.0, occupied_s=25.0, seat_s=60.0)
    ]
    m = compute_fleet_metrics(rides, vehicles, capacity_seats=6)
    assert (m["requests_made"], m["requests_picked_up"], m["requests_served"]) == (3, 2, 2)
    assert m["wait_s"]["median"] == pytest.approx(20.0)
    assert m["ride_s"]["median"] == pytest.approx(20.0)
    assert m["utilisation"] == pytest.approx(0.25)
    assert m["seat_occupancy"] == pytest.approx(0.1)
    assert m["km_per_passenger"] == pytest.approx(1.0)  # 3 km / 3 seats delivered
    with pytest.raises(ConfigError, match="capacity_seats"):
        compute_fleet_metrics(rides, vehicles, capacity_seats=0)


def test_fleet_config_rejects_a_sync_period_off_the_tick() -> None:
    with pytest.raises(ConfigError, match="sync_period_s"):
        FleetConfig(sync_period_s=0.015)
    with pytest.raises(ConfigError, match="at least 1 shuttle"):
        FleetConfig(shuttles=0)


def test_a_fleet_shuttle_whose_stack_hangs_is_stopped_by_its_watchdog_and_black_boxed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Fleet runs use the single run's loop: watchdog events and black-box recordings per shuttle."""
    from lastmile.recorder.run_log import RunLog
    from lastmile.stack.shuttle_stack import ShuttleStack

    stacks: list[ShuttleStack] = []
    frozen: dict[int, object] = {}
    real_init, real_tick = ShuttleStack.__init__, ShuttleStack.tick

    def init(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        real_init(self, *args, **kwargs)
        stacks.append(self)

    def tick(self, now, frames, safety=None):  # type: ignore[no-untyped-def]
        # The second shuttle's control loop freezes at 15 s: it keeps re-sending its last output.
        if self is not stacks[1] or int(now) < 15_000_000:
            frozen[id(self)] = real_tick(self, now, frames, safety)
        return frozen[id(self)]

    monkeypatch.setattr(ShuttleStack, "__init__", init)
    monkeypatch.setattr(ShuttleStack, "tick", tick)
    run_fleet(
        FleetConfig(shuttles=2, minutes=0.4, seed=3, demand_per_pair_per_h=0.0, cameras=False), tmp_path
    )
    logs = [RunLog.load(tmp_path / f"shuttle-{k}") for k in range(2)]
    assert not logs[0].events_of("hardware_watchdog") and not logs[0].events_of("recording")
    (trip,) = logs[1].events_of("hardware_watchdog")
    assert 15.09 <= trip.t_s <= 15.12, trip
    t, v = logs[1].column("t_s"), logs[1].column("speed_mps")
    assert v[t < 15.0].max() > 2.0 and v[-1] < 0.05  # the relay's brake stopped it
    # Triggers close in time share a file: the watchdog's is among the file's triggers.
    files = [e for e in logs[1].events_of("recording") if "watchdog" in e.data["triggers"]]
    assert (
        len(files) == 1 and Path(str(files[0].data["path"])).parent == tmp_path / "shuttle-1" / "recordings"
    )
