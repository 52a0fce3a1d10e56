"""The campus map's signalised crossing: Lanelet2 traffic-light rules read into the map API."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.errors import MapError
from lastmile.hdmap import campus_layout as lay
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop


def test_the_signalised_crossing_has_two_signals_each_with_two_three_bulb_heads() -> None:
    hdmap = load_campus_map()
    assert len(hdmap.signals) == 2
    for sig in hdmap.signals:
        assert len(sig.heads) == 2
        assert sig.bulb_colours == ("red", "yellow", "green") * 2
        line = next(sl for sl in hdmap.stop_lines if sl.id == sig.stop_line_id)
        assert line.signal_id == sig.id and line.all_way_stop_id is None
        heights = sorted(h.z_m for h in sig.heads)
        assert heights == pytest.approx([lay.SIGNAL_POLE_Z_M + 0.5, lay.SIGNAL_OVERHEAD_Z_M + 0.5])
        for head in sig.heads:
            # Lenses face the stop line (the approaching traffic), which is 2 + 4 + 3 m before the head.
            dx, dy = head.stop_x_m - head.x_m, head.stop_y_m - head.y_m
            assert math.cos(head.facing_rad - math.atan2(dy, dx)) > 0.8
            assert 8.0 < math.hypot(dx, dy) < 11.0
            bulbs = sig.bulb_xyz_m[[i for i, h in enumerate(sig.bulb_head_ids) if h == head.light_id]]
            # Red on top, one bulb a third of the housing apart, all inside the housing.
            assert np.all(np.diff(bulbs[:, 2]) < 0)
            assert np.all(np.abs(bulbs[:, 2] - head.z_m) < head.height_m / 2)
    assert len(hdmap.traffic_lights) == 4


def test_the_service_route_crosses_one_signalised_stop_line_before_stop_s2() -> None:
    hdmap = load_campus_map()
    db = SLayerDatabase.build(hdmap, campus_shuttle_loop(hdmap), step_m=1.0, closed=True)
    (line,) = db.signal_stop_lines
    s2 = next(r for r in db.stops if r.stop.id == "S2")
    assert 40.0 < s2.s_start_m - line.s_m < 70.0
    x, y, _ = db.centerline.point_at(line.s_m)
    mid = line.stop_line.line.mean(axis=0)
    assert math.hypot(x - mid[0], y - mid[1]) < 2.0  # the line spans the lane; the route runs through it


def test_asking_for_an_unknown_signal_raises() -> None:
    with pytest.raises(MapError, match="expected a traffic signal among"):
        load_campus_map().signal(123456789)
