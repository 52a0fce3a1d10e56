"""Writes Lanelet2 maps the way a surveyor's map would give them to the routing graph.

Lanelets that follow each other share their end points (points are shared by position), and
side-by-side lanelets share their boundary line string, so Lanelet2's routing graph connects them. Used
by the built-in campus (``campus.py``) and the example town (``town.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import lanelet2.core as ll2

from lastmile.core.geometry import FloatArray


class OsmBuilder:
    """Primitives with sequential ids; points are shared by position so junctions connect."""

    def __init__(self) -> None:
        self.map = ll2.LaneletMap()
        self._next_id = 1
        self._points: dict[tuple[float, float], Any] = {}

    def new_id(self) -> int:
        self._next_id += 1
        return self._next_id - 1

    def point(self, x: float, y: float, z: float = 0.0, **attrs: str) -> Any:
        key = (round(x, 4), round(y, 4))
        if attrs or z != 0.0:  # landmarks are their own points, never merged into road geometry
            p = ll2.Point3d(self.new_id(), x, y, z, ll2.AttributeMap(attrs))
            self.map.add(p)
            return p
        if key not in self._points:
            self._points[key] = ll2.Point3d(self.new_id(), key[0], key[1], 0.0)
        return self._points[key]

    def line(self, xy: FloatArray | Sequence[tuple[float, float]], type_: str, subtype: str = "") -> Any:
        attrs = {"type": type_} | ({"subtype": subtype} if subtype else {})
        pts = [self.point(float(x), float(y)) for x, y in xy]
        return ll2.LineString3d(self.new_id(), pts, ll2.AttributeMap(attrs))

    def lanelet(
        self, left: Any, right: Any, limit_kmh: int | None, subtype: str = "road", **attrs: str
    ) -> Any:
        """A lanelet; ``limit_kmh`` None leaves the speed limit unmapped."""
        base = {
            "type": "lanelet",
            "subtype": subtype,
            "location": "urban",
            "one_way": "yes" if subtype != "crosswalk" else "no",
        } | ({"speed_limit": f"{limit_kmh} km/h"} if limit_kmh is not None else {})
        lanelet = ll2.Lanelet(self.new_id(), left, right, ll2.AttributeMap(base | attrs))
        self.map.add(lanelet)
        return lanelet

    def sign(self, x: float, y: float, heading_rad: float, subtype: str, height_m: float = 2.0) -> Any:
        """A sign plate 0.6 m wide facing traffic that drives along ``heading_rad``."""
        hx, hy = 0.3 * math.sin(heading_rad), -0.3 * math.cos(heading_rad)
        pts = [self.point(x - hx, y - hy, height_m), self.point(x + hx, y + hy, height_m)]
        ls = ll2.LineString3d(
            self.new_id(), pts, ll2.AttributeMap({"type": "traffic_sign", "subtype": subtype})
        )
        self.map.add(ls)
        return ls

    def area(self, corners: Sequence[tuple[float, float]], subtype: str, line_type: str, **attrs: str) -> Any:
        """A closed area whose every side is its own line string (a building's facades, say)."""
        sides = [
            self.line([corners[i], corners[(i + 1) % len(corners)]], line_type) for i in range(len(corners))
        ]
        area = ll2.Area(self.new_id(), sides, [], ll2.AttributeMap({"subtype": subtype} | attrs))
        self.map.add(area)
        return area

    def traffic_light_head(
        self, cx: float, cy: float, z: float, heading_rad: float, width_m: float, height_m: float
    ) -> Any:
        """A red-yellow-green head facing traffic that drives along ``heading_rad``.

        The head is a ``traffic_light`` line string across the bottom of the housing (``height`` its
        height), left to right as the approaching driver sees it; its bulbs are a ``light_bulbs`` line
        string (Autoware's convention: points tagged ``color``, the head's id in ``traffic_light_id``),
        red on top, a bulb every third of the housing.
        """
        ux, uy = math.sin(heading_rad), -math.cos(heading_rad)
        half = width_m / 2
        pts = [self.point(cx - half * ux, cy - half * uy, z), self.point(cx + half * ux, cy + half * uy, z)]
        attrs = {"type": "traffic_light", "subtype": "red_yellow_green", "height": f"{height_m:g}"}
        head = ll2.LineString3d(self.new_id(), pts, ll2.AttributeMap(attrs))
        self.map.add(head)
        bulbs = [
            self.point(cx, cy, z + height_m * (5 - 2 * k) / 6, color=colour)
            for k, colour in enumerate(("red", "yellow", "green"))
        ]
        self.map.add(
            ll2.LineString3d(
                self.new_id(),
                bulbs,
                ll2.AttributeMap({"type": "light_bulbs", "traffic_light_id": str(head.id)}),
            )
        )
        return head
