"""The dispatch service on a route file's loop and stops: ``lastmile serve --route`` and
``lastmile run --fleet N --serve --route``."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.fleet.scheduling import LoopRoute, fleet_stop_ids
from lastmile.hdmap.service_route import campus_service, load_route
from tests.fleet.conftest import ServerProcess

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_ROUTE = ROOT / "examples" / "routes" / "lanelet2_example_roundabout.toml"
EXAMPLE_MAP = ROOT.parent / "shared" / "data" / "maps" / "lanelet2_example" / "mapping_example.osm"
needs_example_map = pytest.mark.skipif(
    not EXAMPLE_MAP.exists(),
    reason="../shared/data/maps/lanelet2_example is absent (real data lives beside the repository)",
)


def _service(*names: str) -> Any:
    return SimpleNamespace(stops=[SimpleNamespace(name=n) for n in names])


def test_map_ids_the_api_can_carry_are_kept_and_named_stops_are_numbered_in_service_order() -> None:
    assert fleet_stop_ids(_service("S1", "S2", "S3", "S4")) == {f"S{k}": f"S{k}" for k in range(1, 5)}
    ids = fleet_stop_ids(_service("K-Block", "Roundabout West", "Library (return)", "<b>x</b>"))
    assert ids == {"K-Block": "K-Block", "Roundabout West": "S2", "Library (return)": "S3", "<b>x</b>": "S4"}
    # A map id that is itself another stop's number never merges two stops.
    clash = fleet_stop_ids(_service("Main Gate", "S1"))
    assert clash == {"Main Gate": "S1_1", "S1": "S1"}


def test_the_campus_dispatch_route_is_the_campus_service() -> None:
    route = LoopRoute(campus_service())
    assert route.order == ("S1", "S2", "S3", "S4")
    assert route.length_m == pytest.approx(campus_service().length_m)


@needs_example_map
def test_serve_on_a_route_file_dispatches_on_its_loop_and_stops(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(ROOT)  # the route file names its map from the repository root
    service = load_route(EXAMPLE_ROUTE)
    (tmp_path / "runs").mkdir()
    proc = ServerProcess(tmp_path / "serve", tmp_path / "runs", route=EXAMPLE_ROUTE).start()
    try:
        with proc.client("rider") as rider:
            served = rider.get("/api/map").json()
            assert served["loop"] and len(served["stops"]) == len(service.stops)
            names = {s["name"] for s in served["stops"]}
            assert {stop.name for stop in service.stops} <= names | {s["id"] for s in served["stops"]}
            first, second = (s["id"] for s in served["stops"][:2])
            res = rider.post("/api/rides", json={"origin": first, "destination": second})
            assert res.status_code == 201, res.text
            assert rider.post("/api/rides", json={"origin": first, "destination": "S99"}).status_code == 404
    finally:
        proc.stop()


@pytest.mark.parametrize("command", [["serve"], ["run", "--fleet", "1", "--serve"]])
def test_a_bad_route_is_one_line_before_the_server_starts(tmp_path: Path, command: list[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[map]\npath = "nowhere.osm"\n')
    result = CliRunner().invoke(app, [*command, "--route", str(bad), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    assert not (tmp_path / "out" / "tokens.json").exists()
