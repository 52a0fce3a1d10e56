"""Writes small hand-made Lanelet2 OSM files for tests: nodes in metres about (49 N, 8.4 E)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lastmile.hdmap.projection import MapProjection, ProjectionKind

ORIGIN_LAT_DEG, ORIGIN_LON_DEG = 49.0, 8.4
_UTM = MapProjection(kind=ProjectionKind.UTM, origin_lat_deg=ORIGIN_LAT_DEG, origin_lon_deg=ORIGIN_LON_DEG)


@dataclass
class OsmBuilder:
    """Nodes, ways and relations of one OSM file; ids are handed out in order."""

    local_tags: bool = False  # also write Autoware local_x/local_y tags (metres, as given)
    local_offset: tuple[float, float] = (0.0, 0.0)
    _next: int = 1
    _nodes: dict[tuple[float, float], int] = field(default_factory=dict)
    _node_tags: dict[int, dict[str, str]] = field(default_factory=dict)
    _lines: list[str] = field(default_factory=list)

    def _id(self) -> int:
        self._next += 1
        return self._next - 1

    def node(self, x: float, y: float, **tags: str) -> int:
        key = (round(x, 6), round(y, 6))
        if key not in self._nodes or tags:
            nid = self._id()
            self._nodes[key] = nid
            self._node_tags[nid] = dict(tags)
            lat, lon = _UTM.latlon_from_xy(np.array([[x, y]]))[0]
            body = "".join(f"<tag k='{k}' v='{v}'/>" for k, v in tags.items())
            if self.local_tags:
                body += (
                    f"<tag k='local_x' v='{x + self.local_offset[0]:.4f}'/>"
                    f"<tag k='local_y' v='{y + self.local_offset[1]:.4f}'/>"
                )
            self._lines.append(f"<node id='{nid}' lat='{lat:.11f}' lon='{lon:.11f}'>{body}</node>")
        return self._nodes[key]

    def way(self, points: list[tuple[float, float]], **tags: str) -> int:
        refs = [self.node(x, y) for x, y in points]
        wid = self._id()
        body = "".join(f"<nd ref='{r}'/>" for r in refs)
        body += "".join(f"<tag k='{k}' v='{v}'/>" for k, v in tags.items())
        self._lines.append(f"<way id='{wid}'>{body}</way>")
        return wid

    def lanelet(
        self,
        left: int,
        right: int,
        rules: tuple[int, ...] = (),
        **tags: str,
    ) -> int:
        rid = self._id()
        members = (
            f"<member type='way' role='left' ref='{left}'/><member type='way' role='right' ref='{right}'/>"
        )
        members += "".join(f"<member type='relation' role='regulatory_element' ref='{r}'/>" for r in rules)
        all_tags = {"type": "lanelet", "subtype": "road", "location": "urban", "one_way": "yes", **tags}
        body = "".join(f"<tag k='{k}' v='{v}'/>" for k, v in all_tags.items())
        self._lines.append(f"<relation id='{rid}'>{members}{body}</relation>")
        return rid

    def relation(self, members: list[tuple[str, str, int]], **tags: str) -> int:
        """members: (type, role, ref)."""
        rid = self._id()
        body = "".join(f"<member type='{t}' role='{r}' ref='{ref}'/>" for t, r, ref in members)
        body += "".join(f"<tag k='{k}' v='{v}'/>" for k, v in tags.items())
        self._lines.append(f"<relation id='{rid}'>{body}</relation>")
        return rid

    def reserve(self) -> int:
        """An id for a relation written later (lanelets that reference a rule need its id first)."""
        return self._id()

    def relation_with_id(self, rid: int, members: list[tuple[str, str, int]], **tags: str) -> int:
        body = "".join(f"<member type='{t}' role='{r}' ref='{ref}'/>" for t, r, ref in members)
        body += "".join(f"<tag k='{k}' v='{v}'/>" for k, v in tags.items())
        self._lines.append(f"<relation id='{rid}'>{body}</relation>")
        return rid

    def write(self, path: Path) -> Path:
        nodes = [ln for ln in self._lines if ln.startswith("<node")]
        ways = [ln for ln in self._lines if ln.startswith("<way")]
        rels = [ln for ln in self._lines if ln.startswith("<relation")]
        text = "<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' generator='test'>\n"
        text += "\n".join(nodes + ways + rels) + "\n</osm>\n"
        path.write_text(text, encoding="utf-8")
        return path


def straight_lane(
    b: OsmBuilder,
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    width_m: float = 3.5,
    right_type: str = "line_thin",
    left_type: str = "line_thin",
    rules: tuple[int, ...] = (),
    **tags: str,
) -> int:
    """A lanelet from (x0, y0) to (x1, y1) (bounds half a width either side), with a middle vertex."""
    dx, dy = x1 - x0, y1 - y0
    n = math.hypot(dx, dy)
    lx, ly = -dy / n * width_m / 2, dx / n * width_m / 2
    mid = ((x0 + x1) / 2, (y0 + y1) / 2)
    left = b.way([(x0 + lx, y0 + ly), (mid[0] + lx, mid[1] + ly), (x1 + lx, y1 + ly)], type=left_type)
    right = b.way([(x0 - lx, y0 - ly), (mid[0] - lx, mid[1] - ly), (x1 - lx, y1 - ly)], type=right_type)
    return b.lanelet(left, right, rules=rules, **tags)


def two_way_stop(b: OsmBuilder, sign_type: str, with_line: bool = True) -> dict[str, int]:
    """An eastbound road whose first lanelet ends at a stop sign's line (x = 40)."""
    rule = b.reserve()
    ids = {
        "in": straight_lane(b, 0, 0, 40, 0, rules=(rule,), speed_limit="30"),
        "out": straight_lane(b, 40, 0, 80, 0, speed_limit="30"),
        "sign": b.way([(38, -3.0), (38, -3.6)], type="traffic_sign", subtype=sign_type),
        "rule": rule,
    }
    members = [("way", "refers", ids["sign"])]
    if with_line:
        ids["line"] = b.way([(40, -1.75), (40, 1.75)], type="stop_line")
        members.append(("way", "ref_line", ids["line"]))
    b.relation_with_id(rule, members, type="regulatory_element", subtype="traffic_sign")
    return ids
