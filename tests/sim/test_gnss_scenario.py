"""The scenario's [gnss] table drives the simulated receiver: quality, outages, regions, snow, slip."""

from pathlib import Path

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.gnss_messages import GnssQuality
from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.service_route import campus_service
from lastmile.sim.gnss_scenario import GnssOutage, GnssRegion, GnssScenario
from lastmile.sim.scenario import Scenario, load_scenario
from lastmile.sim.simulation import Simulation


@pytest.fixture(scope="module")
def service():
    return campus_service()


def _frames(scenario: Scenario, service, seconds: float) -> list:
    sim = Simulation(scenario, service.hdmap, service.polyline, VehicleGeometry(), 10_000)
    out = []
    for tick in range(round(seconds * 100)):
        sim.sensors.sample(tick)
        out += sim.sensors.deliver(tick * 10_000)
    return out


def _gnss(frames) -> list[GnssInsFrame]:
    return [f for f in frames if isinstance(f, GnssInsFrame)]


def test_an_outage_window_from_the_scenario_file_takes_the_fix_away_then_rtk_returns(tmp_path: Path, service):
    path = tmp_path / "s.toml"
    path.write_text("minutes = 1.0\n[gnss]\noutages = [{start_s = 1.0, duration_s = 1.5}]\n")
    frames = _gnss(_frames(load_scenario(path), service, 4.0))
    during = [f for f in frames if 1.0 <= f.stamp / 1e6 < 2.5]
    after = [f for f in frames if f.stamp / 1e6 >= 2.5]
    before = [f for f in frames if f.stamp / 1e6 < 1.0]
    assert during and not any(f.fix_ok for f in during)
    assert all(f.pos_std_m >= 5.0 for f in during)  # the receiver says its guess is worthless
    assert before and after
    assert all(f.fix_ok and f.quality is GnssQuality.RTK_FIXED for f in before + after)
    assert all(f.pos_std_m < 0.02 for f in before + after)


def test_a_region_along_the_route_degrades_the_fix_to_float_with_its_covariance(service):
    gnss = GnssScenario(regions=(GnssRegion(quality="rtk_float", from_route_s_m=-5.0, to_route_s_m=20.0),))
    frames = _gnss(_frames(Scenario(minutes=1.0, gnss=gnss), service, 1.0))
    assert frames and all(f.fix_ok and f.quality is GnssQuality.RTK_FLOAT for f in frames)
    # Float is decimetre-level; the receiver reports half its real sigma (formal covariances are optimistic).
    assert all(f.pos_std_m == pytest.approx(0.5 * 0.2) for f in frames)


def test_the_degraded_receiver_repeats_bit_for_bit_and_leaves_the_plain_model_alone(service):
    gnss = GnssScenario(outages=(GnssOutage(start_s=0.5, duration_s=0.5),))
    a = _gnss(_frames(Scenario(minutes=1.0, gnss=gnss), service, 1.5))
    b = _gnss(_frames(Scenario(minutes=1.0, gnss=gnss), service, 1.5))
    assert a == b
    plain = _frames(Scenario(minutes=1.0), service, 1.5)
    assert all(f.fix_ok and f.pos_std_m == pytest.approx(0.02) for f in _gnss(plain))


def test_wheels_over_read_on_snow_only_when_the_scenario_asks(service):
    gnss = GnssScenario(wheel_slip_on_snow=True, wheel_slip_scale=0.03, wheel_slip_std=0.0)
    snow = Simulation(
        Scenario(minutes=1.0, weather="snow", gnss=gnss),
        service.hdmap,
        service.polyline,
        VehicleGeometry(),
        10_000,
    )
    clear = Simulation(
        Scenario(minutes=1.0, gnss=gnss), service.hdmap, service.polyline, VehicleGeometry(), 10_000
    )
    assert snow.sensors.wheel_slip is not None and clear.sensors.wheel_slip is None
    assert snow.sensors.wheel_slip.corrupt(5.0, np.random.default_rng(0)) == pytest.approx(5.15)


def test_a_region_with_both_a_polygon_and_a_route_stretch_is_one_clear_error(tmp_path: Path):
    path = tmp_path / "s.toml"
    path.write_text(
        "[gnss]\nregions = [{polygon = [[0, 0], [1, 0], [1, 1]], from_route_s_m = 0.0, to_route_s_m = 5.0}]\n"
    )
    with pytest.raises(ConfigError, match="expected either polygon or from_route_s_m"):
        load_scenario(path)


def test_a_scenario_with_gnss_degradation_writes_back_to_an_equal_toml(tmp_path: Path):
    from lastmile.sim.scenario import scenario_to_toml

    gnss = GnssScenario(
        outages=(GnssOutage(start_s=3.0, duration_s=2.0),),
        regions=(GnssRegion(quality="single", polygon=((0.0, 0.0), (5.0, 0.0), (5.0, 5.0))),),
        snow_outages=True,
    )
    path = tmp_path / "s.toml"
    path.write_text(scenario_to_toml(Scenario(gnss=gnss)))
    assert load_scenario(path).gnss == gnss


def test_an_unknown_quality_names_the_choices(tmp_path: Path):
    path = tmp_path / "s.toml"
    path.write_text('[gnss]\noutages = [{start_s = 1.0, duration_s = 1.0, quality = "rtk_fix"}]\n')
    with pytest.raises(ConfigError, match="expected one of"):
        load_scenario(path)


@pytest.mark.parametrize(
    ("range_m", "quality"), [(15.0, GnssQuality.RTK_FIXED), (25.0, GnssQuality.RTK_FLOAT)]
)
def test_multipath_degrades_the_fix_only_within_its_range_of_the_map_buildings(service, range_m, quality):
    # Route s 1200 m passes a building 18.2 m away.
    gnss = GnssScenario(multipath=True, multipath_range_m=range_m)
    frames = _gnss(_frames(Scenario(minutes=1.0, start_route_s_m=1200.0, gnss=gnss), service, 1.0))
    assert frames and all(f.fix_ok and f.quality is quality for f in frames)
