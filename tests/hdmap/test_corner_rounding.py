"""Corners the shuttle cannot steer become fillets of the steerable radius, within the road."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap import corner_rounding
from lastmile.hdmap.corner_rounding import max_curvature_per_m, round_corners
from lastmile.hdmap.service_route import campus_service

GEOMETRY = VehicleGeometry()


class _Road:
    """A road outline stub: everything on the road, or only within ``half_m`` of the mapped line."""

    def __init__(self, line: np.ndarray | None = None, half_m: float = 0.0) -> None:
        self.line = Polyline(line) if line is not None else None
        self.half_m = half_m

    def contains(self, pts: np.ndarray) -> np.ndarray:
        if self.line is None:
            return np.ones(len(pts), dtype=bool)
        return np.array([abs(self.line.project(float(x), float(y)).d_m) <= self.half_m for x, y in pts])


def _kinked(angle_deg: float) -> np.ndarray:
    """40 m east, then 40 m at ``angle_deg`` to the left, vertices every 2 m (a mapper's clicks)."""
    a = math.radians(angle_deg)
    first = np.c_[np.arange(0.0, 40.0, 2.0), np.zeros(20)]
    k = np.arange(0.0, 40.01, 2.0)
    second = np.c_[40.0 + k * math.cos(a), k * math.sin(a)]
    return np.vstack([first, second])


def _peak_turn_per_m(xy: np.ndarray) -> float:
    line = Polyline(xy)
    s = np.arange(3.0, line.length_m - 3.0, 0.25)
    return max(abs(line.curvature_at(float(q), window_m=1.5)) for q in s)


@pytest.mark.parametrize("angle_deg", [35.0, 80.0])
def test_a_kink_becomes_a_fillet_of_the_steerable_radius(
    monkeypatch: pytest.MonkeyPatch, angle_deg: float
) -> None:
    xy = _kinked(angle_deg)
    monkeypatch.setattr(corner_rounding, "RoadOutline", lambda hdmap: _Road())
    out = round_corners(None, xy, closed=False)  # type: ignore[arg-type]
    kappa_max = max_curvature_per_m(GEOMETRY)
    assert _peak_turn_per_m(xy) > 3.0 * kappa_max  # as mapped: far beyond what the shuttle steers
    assert _peak_turn_per_m(out) <= 1.1 * kappa_max
    # The ends stay where they were; the corner is cut by R (1 / cos(a / 2) - 1) at most.
    assert np.allclose(out[0], xy[0]) and np.allclose(out[-1], xy[-1])
    a = math.radians(angle_deg)
    cut = (1.0 / math.cos(a / 2.0) - 1.0) / kappa_max
    corner = Polyline(out).project(40.0, 0.0)
    assert abs(corner.d_m) == pytest.approx(cut, abs=0.1)


def test_a_fillet_that_would_leave_the_road_is_not_taken(monkeypatch: pytest.MonkeyPatch) -> None:
    """A road only as wide as the shuttle around the mapped line: the corner stays as drawn."""
    xy = _kinked(80.0)
    road = _Road(xy, half_m=GEOMETRY.width_m / 2.0 + 0.05)
    monkeypatch.setattr(corner_rounding, "RoadOutline", lambda hdmap: road)
    assert round_corners(None, xy, closed=False) is xy  # type: ignore[arg-type]


def test_the_campus_loop_has_no_corner_to_round() -> None:
    service = campus_service()
    xy = service.polyline.xy_m
    assert round_corners(service.hdmap, xy, closed=True) is xy
