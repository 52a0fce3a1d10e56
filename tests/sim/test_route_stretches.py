"""The scenario generator on a route file's map: encounters on the route's own free stretches."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.errors import ConfigError
from lastmile.sim.route_stretches import MIN_STRETCH_M, free_stretches
from lastmile.sim.scenario_generator import ScenarioSpace, sample_scenarios

ROOT = Path(__file__).resolve().parents[2]
BITS_MAP = ROOT.parent / "shared" / "data" / "maps" / "campus_shuttle_bits"


def _service(
    length_m: float, stops_s: list[float], junctions: list[tuple[float, float]] = (), crossings=()
) -> Any:
    layers = SimpleNamespace(crosswalks=[SimpleNamespace(s_start_m=a, s_end_m=b) for a, b in crossings])
    return SimpleNamespace(
        name="test loop",
        length_m=length_m,
        stops=[SimpleNamespace(route_s_m=s) for s in stops_s],
        intersections=lambda: list(junctions),
        layers=lambda step_m: layers,
    )


def test_stretches_keep_the_clearance_from_stops_junctions_and_crosswalks_round_the_loop() -> None:
    # Stop at 10 m (its clearance wraps past the start to 960 m), a junction 400-420, a crosswalk 700-705.
    free = free_stretches(_service(1000.0, [10.0], [(400.0, 420.0)], [(700.0, 705.0)]), clearance_m=50.0)
    assert free == ((60.0, 350.0), (470.0, 650.0), (755.0, 960.0))


def test_slivers_are_dropped_and_a_loop_with_no_room_is_one_clear_error() -> None:
    # Between the stops at 0 and 120 m only 16 m stay clear of both: under MIN_STRETCH_M, dropped.
    assert MIN_STRETCH_M > 16.0
    assert free_stretches(_service(300.0, [0.0, 120.0]), clearance_m=52.0) == ((172.0, 248.0),)
    with pytest.raises(
        ConfigError, match=r"route 'test loop': expected a stretch .* got none on its 192 m loop"
    ):
        free_stretches(_service(192.0, [16.0, 47.0, 96.0, 135.0], [(128.0, 163.0)]), clearance_m=45.0)


@pytest.mark.skipif(
    not BITS_MAP.exists(),
    reason="../shared/data/maps/campus_shuttle_bits is absent (real data lives beside the repository)",
)
def test_generated_scenarios_on_a_route_use_its_map_and_stretches_and_nothing_campus_only(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(ROOT)  # the route file names its map from the repository root
    route = "examples/routes/bits_campus_loop.toml"
    space = ScenarioSpace(route=route, pedestrians=(2, 2), cars=(2, 2), cyclists=(1, 1), geese=(1, 1))
    from lastmile.hdmap.service_route import load_route

    stretches = free_stretches(load_route(route), clearance_m=space.trigger_m[1])
    scenarios = sample_scenarios(space, 6, seed=4)
    assert scenarios == sample_scenarios(space, 6, seed=4)  # one seed, the same scenarios
    for sc in scenarios:
        assert sc.map.name == "route" and sc.map.route == route
        assert sc.side_road_cars == ()  # the campus's side road does not exist there
        assert all(car.direction == "ccw" for car in sc.ring_cars)  # every car follows the service path
        for placed in (*sc.walkers, *sc.static_obstacles):
            assert any(lo <= placed.route_s_m <= hi for lo, hi in stretches), placed


def test_route_goes_with_generate_only(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app, ["sweep", "--suite", "iso22737", "--route", "r.toml", "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 2 and "expected it with --generate" in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
