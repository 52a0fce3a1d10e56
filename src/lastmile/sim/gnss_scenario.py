"""The scenario's ``[gnss]`` table: GNSS fix quality, outages, multipath, heavy snow and wheel slip.

Without the table (or with every item off) the simulator keeps its plain RTK GNSS/INS model, so older
scenarios run bit for bit as before. With it, the GNSS solution comes from
:class:`lastmile.sim.gnss_degradation.GnssDegradation` and, on snow, the wheel speed from
:class:`lastmile.sim.gnss_degradation.WheelSlip`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from lastmile.core.config import check_range
from lastmile.core.errors import ConfigError
from lastmile.core.gnss_messages import GnssQuality
from lastmile.core.polyline import Polyline
from lastmile.hdmap.model import HDMap
from lastmile.sim.gnss_degradation import GnssDegradation, GnssDegradationConfig, OutageRegion, WheelSlip

RegionQuality = Literal["none", "single", "dgnss", "rtk_float"]
"""The best solution inside a degraded region or window ("none": no fix at all)."""


def gnss_quality(quality: RegionQuality) -> GnssQuality | None:
    """The receiver's solution type for a scenario's quality name (None: no fix)."""
    return None if quality == "none" else GnssQuality(quality)


@dataclass(frozen=True, slots=True, kw_only=True)
class GnssOutage:
    """No fix anywhere from ``start_s`` for ``duration_s`` (simulated seconds): a receiver fault, a
    jammer, an antenna cable. ``quality`` other than "none" degrades the fix instead of removing it."""

    start_s: float
    duration_s: float
    quality: RegionQuality = "none"

    def __post_init__(self) -> None:
        check_range("gnss.outages.start_s", self.start_s, 0.0, 24 * 3600.0)
        check_range("gnss.outages.duration_s", self.duration_s, 0.0, 24 * 3600.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class GnssRegion:
    """A place where the sky is blocked (underpass, tree canopy, a narrow court between buildings).

    Give either ``polygon`` (map-frame outline, at least 3 [x, y] points, m) or a stretch of the service
    route, ``from_route_s_m`` to ``to_route_s_m`` (a corridor ``half_width_m`` either side of it).
    It is active from ``start_s`` until ``end_s`` (None: to the end of the run).
    """

    quality: RegionQuality = "none"
    polygon: tuple[tuple[float, float], ...] = ()
    from_route_s_m: float | None = None
    to_route_s_m: float | None = None
    half_width_m: float = 10.0
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        by_route = self.from_route_s_m is not None or self.to_route_s_m is not None
        if bool(self.polygon) == by_route:
            raise ConfigError(
                "gnss.regions: expected either polygon or from_route_s_m/to_route_s_m, got "
                f"polygon={list(self.polygon)!r}, from_route_s_m={self.from_route_s_m!r}, "
                f"to_route_s_m={self.to_route_s_m!r}"
            )
        if self.polygon and (len(self.polygon) < 3 or any(len(p) != 2 for p in self.polygon)):
            raise ConfigError(
                f"gnss.regions.polygon: expected at least 3 [x, y] points, got {list(self.polygon)!r}"
            )
        if by_route and (
            self.from_route_s_m is None
            or self.to_route_s_m is None
            or self.to_route_s_m <= self.from_route_s_m
        ):
            raise ConfigError(
                "gnss.regions: expected from_route_s_m < to_route_s_m, got "
                f"{self.from_route_s_m!r} and {self.to_route_s_m!r}"
            )
        check_range("gnss.regions.half_width_m", self.half_width_m, 0.5, 100.0)
        if self.end_s is not None and not self.end_s > self.start_s:
            raise ConfigError(f"gnss.regions: expected end_s > start_s, got {self.end_s} <= {self.start_s}")

    def outline(self, route: Polyline) -> np.ndarray:
        """(N, 2) outline in the map frame."""
        if self.polygon:
            return np.asarray(self.polygon, dtype=float)
        assert self.from_route_s_m is not None and self.to_route_s_m is not None
        s = np.linspace(
            self.from_route_s_m, self.to_route_s_m, max(2, int(self.to_route_s_m - self.from_route_s_m))
        )
        left, right = [], []
        for si in s:
            x, y, yaw = route.point_at(float(si))
            nx, ny = -math.sin(yaw) * self.half_width_m, math.cos(yaw) * self.half_width_m
            left.append((x + nx, y + ny))
            right.append((x - nx, y - ny))
        return np.asarray(left + right[::-1], dtype=float)


@dataclass(frozen=True, slots=True, kw_only=True)
class GnssScenario:
    """How GNSS and wheel odometry degrade in this world (the scenario's ``[gnss]`` table).

    Attributes:
        outages: windows in time with no (or a degraded) fix everywhere.
        regions: places with no (or a degraded) fix.
        multipath: RTK degrades to float with a correlated bias near the map's buildings (within
            ``multipath_range_m``; the campus loop passes its buildings at 18 m and more, so there the
            default 15 m leaves RTK fixed).
        multipath_range_m: a facade closer than this degrades the solution, m.
        snow_outages: in snow, heavy snow on the antenna takes the fix away (Poisson starts,
            ``snow_outages_per_hour``, exponential lengths of mean ``snow_outage_mean_s``).
        wheel_slip_on_snow: in snow the wheels over-read by ``wheel_slip_scale`` (spin) with a slip
            noise of ``wheel_slip_std`` of the speed.
    """

    outages: tuple[GnssOutage, ...] = ()
    regions: tuple[GnssRegion, ...] = ()
    multipath: bool = False
    multipath_range_m: float = 15.0  # GnssDegradationConfig's default (a campus building)
    snow_outages: bool = False
    snow_outages_per_hour: float = 6.0
    snow_outage_mean_s: float = 30.0
    wheel_slip_on_snow: bool = False
    wheel_slip_scale: float = 0.03
    wheel_slip_std: float = 0.02
    reported_sigma_factor: float = 0.5

    def __post_init__(self) -> None:
        check_range("gnss.multipath_range_m", self.multipath_range_m, 0.1, 500.0)
        check_range("gnss.snow_outages_per_hour", self.snow_outages_per_hour, 0.0, 3600.0)
        check_range("gnss.snow_outage_mean_s", self.snow_outage_mean_s, 0.1, 3600.0)
        check_range("gnss.wheel_slip_scale", self.wheel_slip_scale, -0.5, 0.5)
        check_range("gnss.wheel_slip_std", self.wheel_slip_std, 0.0, 0.5)
        check_range("gnss.reported_sigma_factor", self.reported_sigma_factor, 0.01, 10.0)

    @property
    def degrades_gnss(self) -> bool:
        """Whether the receiver model replaces the plain RTK one."""
        return bool(self.outages or self.regions or self.multipath or self.snow_outages)

    def receiver(self, hdmap: HDMap, route: Polyline, rng: np.random.Generator) -> GnssDegradation | None:
        """The degraded receiver for this world (None: the plain RTK model stays)."""
        if not self.degrades_gnss:
            return None
        regions = tuple(
            OutageRegion(
                polygon=None,
                quality=gnss_quality(o.quality),
                start_s=o.start_s,
                end_s=o.start_s + o.duration_s,
            )
            for o in self.outages
        ) + tuple(
            OutageRegion(
                polygon=r.outline(route),
                quality=gnss_quality(r.quality),
                start_s=r.start_s,
                end_s=math.inf if r.end_s is None else r.end_s,
            )
            for r in self.regions
        )
        config = GnssDegradationConfig(
            multipath_range_m=self.multipath_range_m,
            snow_outages_per_hour=self.snow_outages_per_hour if self.snow_outages else 0.0,
            snow_outage_mean_s=self.snow_outage_mean_s,
            reported_sigma_factor=self.reported_sigma_factor,
            regions=regions,
        )
        buildings = [a.polygon for a in hdmap.areas if a.subtype == "building"] if self.multipath else []
        return GnssDegradation(config, buildings, rng)

    def wheel_slip(self, snow: bool) -> WheelSlip | None:
        """The wheel-slip model in this weather (None: the plain odometry model stays)."""
        if not (self.wheel_slip_on_snow and snow):
            return None
        return WheelSlip(scale_error=self.wheel_slip_scale, slip_std=self.wheel_slip_std)
