"""Simulated GNSS degradation: regions, multipath near buildings, snow outages, optimistic sigmas, seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.gnss_messages import GnssQuality
from lastmile.core.stamp import stamp_from_s
from lastmile.sim.gnss_degradation import (
    GnssDegradation,
    GnssDegradationConfig,
    ImuErrorConfig,
    ImuErrors,
    OutageRegion,
    WheelSlip,
)

BUILDING = np.array([[20.0, -10.0], [40.0, -10.0], [40.0, 10.0], [20.0, 10.0]])
TUNNEL = np.array([[-100.0, -5.0], [-80.0, -5.0], [-80.0, 5.0], [-100.0, 5.0]])


def _receiver(seed=0, **kw):
    config = GnssDegradationConfig(regions=(OutageRegion(polygon=TUNNEL),), **kw)
    return GnssDegradation(config, [BUILDING], np.random.default_rng(seed))


def test_open_sky_gives_rtk_fixed_with_an_optimistic_reported_sigma():
    rx = _receiver()
    fixes = [rx.fix(stamp_from_s(0.25 * k), -40.0, 0.0) for k in range(4000)]
    assert all(f is not None and f.quality is GnssQuality.RTK_FIXED for f in fixes)
    err = np.array([f.x_m + 40.0 for f in fixes])
    reported = math.sqrt(fixes[0].var_xx_m2)
    assert np.std(err) == pytest.approx(0.01 / 1.1774, rel=0.05)
    assert reported == pytest.approx(0.5 * np.std(err), rel=0.06)


def test_an_outage_region_has_no_fix_and_a_building_brings_correlated_float_multipath():
    rx = _receiver()
    assert rx.fix(stamp_from_s(0.0), -90.0, 0.0) is None
    fixes = [rx.fix(stamp_from_s(0.25 * k), 15.0, 0.0) for k in range(4000)]  # 5 m from the facade
    assert all(f.quality is GnssQuality.RTK_FLOAT for f in fixes)
    err = np.array([f.x_m - 15.0 for f in fixes])
    expected = math.hypot(0.2, 0.5 * (1.0 - 5.0 / 15.0))
    assert np.std(err) == pytest.approx(expected, rel=0.25)
    lag1 = np.corrcoef(err[:-1], err[1:])[0, 1]
    assert lag1 > 0.5  # multipath persists from fix to fix; white noise would not


def test_heavy_snow_starts_outages_at_the_configured_rate_and_a_seed_repeats():
    def outage_share(seed):
        rx = _receiver(seed, snow_outages_per_hour=60.0, snow_outage_mean_s=10.0)
        fixes = [rx.fix(stamp_from_s(0.25 * k), -40.0, 0.0, heavy_snow=True) for k in range(4 * 3600)]
        return np.mean([f is None for f in fixes]), fixes

    share, a = outage_share(1)
    assert 0.05 < share < 0.3  # 60 per hour of 10 s: about 14 % of the time
    _, b = outage_share(1)
    assert a == b


def test_imu_errors_and_wheel_slip():
    imu = ImuErrors(ImuErrorConfig(), np.random.default_rng(2))
    samples = [imu.corrupt(0.01, 0.0, 0.0) for _ in range(1000)]
    assert np.mean([s[0] for s in samples]) == pytest.approx(imu.gyro_bias_radps, abs=1e-3)
    slip = WheelSlip()
    speeds = [slip.corrupt(5.0, np.random.default_rng(k)) for k in range(500)]
    assert (
        np.mean(speeds) == pytest.approx(5.0 * 1.03, rel=0.01)
        and slip.corrupt(0.0, np.random.default_rng(0)) == 0.0
    )


def test_bad_regions_are_refused():
    with pytest.raises(ConfigError, match=r"OutageRegion\.polygon"):
        GnssDegradationConfig(regions=(OutageRegion(polygon=np.zeros((2, 2))),))
