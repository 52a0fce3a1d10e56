"""``lastmile map check`` on small hand-written maps: report, PNG, exit codes."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.hdmap.map_check import Status, check
from tests.hdmap.osm_builder import OsmBuilder, straight_lane, two_way_stop
from tests.hdmap.test_service_route import _stop, _write, stadium


def test_check_names_what_is_missing_and_what_it_turns_off(tmp_path: Path) -> None:
    b = OsmBuilder()
    stadium(b)
    route = _write(tmp_path, b, _stop("A", 20, -1.0) + _stop("B", 80, 6.0))
    report = check(None, None, route)
    items = {i.layer: i for i in report.items}
    assert not report.has_errors
    assert items["route"].status is Status.OK and "2 stops" in items["route"].detail
    assert items["curbs"].status is Status.OK  # the stadium's outer bounds are curbstone
    assert items["landmarks"].status is Status.MISSING
    assert "GNSS-denied landmark localization" in items["landmarks"].off
    assert (
        items["regulatory elements"].status is Status.MISSING
        and "all-way-stop" in items["regulatory elements"].off
    )


def test_cli_writes_the_png_and_exits_zero_unless_there_are_errors(tmp_path: Path) -> None:
    b = OsmBuilder()
    stadium(b)
    route = _write(tmp_path, b, _stop("A", 20, -1.0) + _stop("B", 80, 6.0))
    png = tmp_path / "out" / "check.png"
    result = CliRunner().invoke(app, ["map", "check", "--route", str(route), "--png", str(png)])
    assert result.exit_code == 0, result.output
    assert "[missing] landmarks" in result.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # A stop 6 m from the lanes: the map loads, the route is an error: exit 1, the reason on one line.
    bad = _write(tmp_path, b, _stop("A", 20, -1.0) + _stop("Far", 50, -12.0))
    result = CliRunner().invoke(app, ["map", "check", "--route", str(bad), "--png", str(png)])
    assert result.exit_code == 1
    assert "'Far'" in result.output and "within 5 m" in result.output
    # A map without a projection: a usage error, one line, no traceback.
    result = CliRunner().invoke(app, ["map", "check", str(tmp_path / "map.osm")])
    assert result.exit_code == 2 and "expected --projector" in result.output
    assert "Traceback" not in result.output


def test_a_map_without_speed_tags_and_no_route_limit_is_reported_not_defaulted(tmp_path: Path) -> None:
    b = OsmBuilder()
    straight_lane(b, 0, 0, 50, 0)
    b.write(tmp_path / "map.osm")
    report = check(tmp_path / "map.osm", "utm:49,8.4", None)
    speed = next(i for i in report.items if i.layer == "speed limits")
    assert speed.status is Status.MISSING and "unmapped_speed_limit_kph" in speed.off


def test_check_lists_the_signs_and_the_stop_lines_a_stop_sign_controls(tmp_path: Path) -> None:
    b = OsmBuilder()
    ids = two_way_stop(b, "de206")
    # A 20 km/h sign whose rule the road beyond the stop references, and one nothing references.
    limit = b.reserve()
    beyond = straight_lane(b, 80, 0, 120, 0, rules=(limit,))
    sign = b.way([(82, -3.0), (82, -3.6)], type="traffic_sign", subtype="de274-20")
    b.relation_with_id(limit, [("way", "refers", sign)], type="regulatory_element", subtype="speed_limit")
    stray = b.way([(10, -3.0), (10, -3.6)], type="traffic_sign", subtype="de274-30")
    stray_rule = b.relation([("way", "refers", stray)], type="regulatory_element", subtype="speed_limit")
    b.write(tmp_path / "map.osm")
    signs = next(
        i for i in check(tmp_path / "map.osm", "utm:49,8.4", None).items if i.layer == "traffic signs"
    )
    assert signs.status is Status.OK
    assert "de206 x1, de274-20 x1, de274-30 x1" in signs.detail
    assert f"rule {limit} (de274-20) sets [20.0] km/h on 1 lanelets ({beyond})" in signs.detail
    assert f"rule {stray_rule} (de274-30) controls no lanelet" in signs.detail
    assert (
        f"rule {ids['rule']}: line {ids['line']} at the end of lanelet {ids['in']} (two-way stop"
        in signs.detail
    )
    b = OsmBuilder()
    straight_lane(b, 0, 0, 50, 0, speed_limit="30")
    b.write(tmp_path / "plain.osm")
    plain = next(
        i for i in check(tmp_path / "plain.osm", "utm:49,8.4", None).items if i.layer == "traffic signs"
    )
    assert plain.status is Status.MISSING and "0 drawn (none)" in plain.detail and "de206" in plain.off
