"""The speed reference a lateral controller may take from the longitudinal one.

A coupled controller (Snow Lion's MPC) predicts with the speed the longitudinal controller is about to
track; the geometric ones steer from the path and the measured speed alone. Every lateral controller
accepts the reference, so the stack hands it over without asking which controller it drives.
"""

from __future__ import annotations

from lastmile.core.polyline import Polyline


class NoSpeedLaw:
    """Mixin of the lateral controllers whose source sets no speed of its own (GEM's does)."""

    def speed_cap_mps(self, path: Polyline, path_s_m: float, cap_mps: float, decel_mps2: float) -> float:
        """The cap, unchanged: the longitudinal controller's curve limit alone applies."""
        del path, path_s_m, decel_mps2
        return cap_mps


class SteersFromPathAlone:
    """Mixin of the lateral controllers that take no speed reference."""

    def set_speed_reference(self, speed_mps: float | None, accel_mps2: float = 0.0) -> None:
        """Ignored: the steering law uses the measured speed only."""
        del speed_mps, accel_mps2
