"""Position-only GNSS fixes (RTKLIB, NMEA, NavSatFix) with their quality and reported covariance."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from lastmile.core.errors import MessageError
from lastmile.core.stamp import Stamp


class GnssQuality(Enum):
    """Solution type as receivers report it (RTKLIB Q, NMEA GGA quality, NavSatStatus)."""

    RTK_FIXED = "rtk_fixed"
    RTK_FLOAT = "rtk_float"
    DGNSS = "dgnss"
    SINGLE = "single"


# Horizontal accuracy, one sigma per axis, m, by solution type: u-blox ZED-F9P datasheet
# (UBX-17051259): RTK 0.01 m + 1 ppm CEP, PVT 1.5 m CEP, SBAS 1.0 m CEP; CEP = 1.1774 sigma for a circular
# Gaussian. Float solutions are decimetre-level (RTKLIB manual, ch. 3): 0.2 m. A receiver's own
# covariance is formal (it assumes white, uncorrelated noise) and is often smaller than this; and the
# error of a solution is not white: atmosphere, orbits and multipath change over tens of seconds to
# minutes. Filters therefore floor each epoch's reported covariance at this figure (the white part)
# and model a Gauss-Markov error of the same sigma with ``ERROR_CORRELATION_S`` (the correlated part).
ACCURACY_FLOOR_M: dict[GnssQuality, float] = {
    GnssQuality.RTK_FIXED: 0.01 / 1.1774,
    GnssQuality.RTK_FLOAT: 0.2,
    GnssQuality.DGNSS: 1.0 / 1.1774,
    GnssQuality.SINGLE: 1.5 / 1.1774,
}
ERROR_CORRELATION_S = 60.0
"""Correlation time of a GNSS solution's error (multipath and atmosphere change over about a minute), s."""


def floored_sigma_m(reported_sigma_m: float, quality: GnssQuality) -> float:
    """A receiver's reported one-sigma accuracy, floored at its solution type's datasheet figure, m."""
    return max(reported_sigma_m, ACCURACY_FLOOR_M[quality])


def white_covariance_m2(fix: GnssFix) -> tuple[float, float, float]:
    """The fix's reported covariance (xx, xy, yy) with each axis floored at its type's accuracy, m^2."""
    floor = ACCURACY_FLOOR_M[fix.quality] ** 2
    return max(fix.var_xx_m2, floor), fix.var_xy_m2, max(fix.var_yy_m2, floor)


@dataclass(frozen=True, slots=True, kw_only=True)
class GnssFix:
    """A GNSS antenna position in the map frame (x east, y north), with its reported covariance.

    Attributes:
        stamp: epoch of the solution, µs.
        x_m, y_m: antenna position in the local map frame, m.
        var_xx_m2, var_xy_m2, var_yy_m2: the receiver's reported horizontal covariance, m².
        quality: solution type.
    """

    stamp: Stamp
    x_m: float
    y_m: float
    var_xx_m2: float
    var_xy_m2: float
    var_yy_m2: float
    quality: GnssQuality

    def validate(self) -> None:
        """Raise MessageError on a non-finite value or a covariance that is not positive definite."""
        for name in ("x_m", "y_m", "var_xx_m2", "var_xy_m2", "var_yy_m2"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise MessageError(f"GnssFix.{name}: expected a finite number, got {value}")
        if not (self.var_xx_m2 > 0 and self.var_yy_m2 > 0):
            raise MessageError(
                f"GnssFix: expected positive variances, got {self.var_xx_m2}, {self.var_yy_m2}"
            )
        if self.var_xy_m2**2 >= self.var_xx_m2 * self.var_yy_m2:
            raise MessageError(
                "GnssFix: expected a positive-definite covariance (var_xy^2 < var_xx * var_yy), got "
                f"{self.var_xx_m2}, {self.var_xy_m2}, {self.var_yy_m2}"
            )
        if not isinstance(self.quality, GnssQuality):
            raise MessageError(f"GnssFix.quality: expected a GnssQuality, got {self.quality!r}")
        if self.stamp < 0:
            raise MessageError(f"GnssFix.stamp: expected a non-negative stamp, got {self.stamp}")
