"""The binned prism caster against a per-ray reference, on random scenes (hypothesis)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.object_class import ObjectClass
from lastmile.sim.agents import Agent
from lastmile.sim.lidar_raycast import Columns, box_pairs, cast, cylinder_pairs, segment_pairs
from lastmile.sim.lidar_rig import lidar_specs_from_config
from lastmile.sim.lidar_scene import DynamicObjects, Segments


def reference_range(o: np.ndarray, d: np.ndarray, oz: float, tan: float, walls, cyls, boxes) -> float:
    """Nearest hit of one ray by the textbook tests, one primitive at a time."""
    best = math.inf
    for p0, p1, z0, z1 in walls:
        e = p1 - p0
        den = d[0] * e[1] - d[1] * e[0]
        if abs(den) < 1e-12:
            continue
        w = p0 - o
        r = (w[0] * e[1] - w[1] * e[0]) / den
        u = (w[0] * d[1] - w[1] * d[0]) / den
        if 0 <= u <= 1 and r > 0 and z0 <= oz + r * tan <= z1:
            best = min(best, r)
    for c, rad, z0, z1 in cyls:
        rel = o - c
        b = rel @ d
        disc = b * b - (rel @ rel - rad * rad)
        if disc < 0:
            continue
        lo, hi = -b - math.sqrt(disc), -b + math.sqrt(disc)
        zlo, zhi = (
            sorted(((z0 - oz) / tan, (z1 - oz) / tan))
            if tan != 0
            else ((-math.inf, math.inf) if z0 <= oz <= z1 else (math.inf, -math.inf))
        )
        lo, hi = max(lo, zlo), min(hi, zhi)
        if hi >= lo and hi > 0:
            best = min(best, max(lo, 1e-6))
    for c, yaw, hl, hw, z0, z1 in boxes:
        cy, sy = math.cos(yaw), math.sin(yaw)
        rel = o - c
        lo_, hi_ = -math.inf, math.inf
        for oo, dd, h in (
            (cy * rel[0] + sy * rel[1], cy * d[0] + sy * d[1], hl),
            (-sy * rel[0] + cy * rel[1], -sy * d[0] + cy * d[1], hw),
            (oz - (z0 + z1) / 2, tan, (z1 - z0) / 2),
        ):
            if dd == 0:
                if abs(oo) > h:
                    lo_, hi_ = math.inf, -math.inf
                continue
            a, b2 = (-h - oo) / dd, (h - oo) / dd
            lo_, hi_ = max(lo_, min(a, b2)), min(hi_, max(a, b2))
        if hi_ >= lo_ and hi_ > 0:
            best = min(best, max(lo_, 1e-6))
    return best


coord = st.floats(-25.0, 25.0)


def _segment_distance(p: np.ndarray, q: np.ndarray) -> float:
    """Distance from the origin (the sensor) to the segment pq."""
    e = q - p
    u = float(np.clip(-(p @ e) / max(float(e @ e), 1e-12), 0.0, 1.0))
    return float(np.hypot(*(p + u * e)))


@settings(max_examples=30, deadline=None)
@given(
    walls=st.lists(
        st.tuples(coord, coord, coord, coord, st.floats(0.0, 1.0), st.floats(0.2, 5.0)), max_size=4
    ),
    cyls=st.lists(st.tuples(coord, coord, st.floats(0.05, 1.0), st.floats(0.3, 4.0)), max_size=3),
    boxes=st.lists(
        st.tuples(
            coord,
            coord,
            st.floats(-math.pi, math.pi),
            st.floats(0.2, 3.0),
            st.floats(0.2, 1.5),
            st.floats(0.3, 3.0),
        ),
        max_size=3,
    ),
    heading=st.floats(-math.pi, math.pi),
)
def test_binned_caster_matches_the_per_ray_reference(walls, cyls, boxes, heading) -> None:
    n_col, oz = 120, 1.2
    spin = np.radians(3.0) * np.arange(n_col)
    theta = heading - spin  # clockwise
    cols = Columns(
        origin=np.zeros((n_col, 2)),
        direction=np.column_stack([np.cos(theta), np.sin(theta)]),
        t_s=np.zeros(n_col),
        spin=spin,
        theta0_rad=heading,
        sign=-1.0,
        z_m=oz,
    )
    tan = np.tan(np.radians(np.linspace(-30.0, 15.0, 9)))
    # A real sensor has a minimum range: nothing is generated within 0.3 m of it.
    walls = [w for w in walls if _segment_distance(np.array(w[:2]), np.array(w[2:4])) > 0.3]
    cyls = [c for c in cyls if math.hypot(c[0], c[1]) > c[2] + 0.3]
    boxes = [b for b in boxes if math.hypot(b[0], b[1]) > math.hypot(b[3], b[4]) / 2 + 0.3]
    wall_rows = [
        (np.array([x0, y0]), np.array([x1, y1]), z0, z0 + h)
        for x0, y0, x1, y1, z0, h in walls
        if math.hypot(x1 - x0, y1 - y0) > 1e-3
    ]
    seg = Segments(
        p0=np.array([w[0] for w in wall_rows]).reshape(-1, 2),
        p1=np.array([w[1] for w in wall_rows]).reshape(-1, 2),
        z_min_m=np.array([w[2] for w in wall_rows]),
        z_max_m=np.array([w[3] for w in wall_rows]),
        label=np.zeros(len(wall_rows), np.int8),
        reflectivity=np.zeros(len(wall_rows)),
        retro=np.zeros(len(wall_rows), bool),
    )
    people = [
        Agent(
            id=i,
            cls=ObjectClass.PEDESTRIAN,
            x_m=x,
            y_m=y,
            yaw_rad=0.0,
            speed_mps=0.0,
            length_m=2 * r,
            width_m=2 * r,
            rcs_dbsm=0.0,
        )
        for i, (x, y, r, _h) in enumerate(cyls)
    ]
    cyl = DynamicObjects.from_agents(people).cylinders
    obj = DynamicObjects.empty()
    for x, y, yaw, length, width, height in boxes:
        obj = obj.with_box(x_m=x, y_m=y, yaw_rad=yaw, length_m=length, width_m=width, height_m=height)
    box = obj.boxes
    parts = [segment_pairs(cols, seg), cylinder_pairs(cols, cyl), box_pairs(cols, box)]
    offsets = (0, len(seg), len(seg) + len(cyl))
    pairs = tuple(
        np.concatenate([p[i] + (off if i == 0 else 0) for p, off in zip(parts, offsets, strict=True)])
        for i in range(5)
    )
    z = (
        np.concatenate([seg.z_min_m, cyl.z_min_m, box.z_min_m]),
        np.concatenate([seg.z_max_m, cyl.z_max_m, box.z_max_m]),
    )
    hits = cast(cols, tan, z, pairs, 1e6)
    ref_cyl = [(cyl.centre[i], cyl.radius_m[i], cyl.z_min_m[i], cyl.z_max_m[i]) for i in range(len(cyl))]
    ref_box = [
        (
            box.centre[i],
            box.yaw_rad[i],
            box.half_length_m[i],
            box.half_width_m[i],
            box.z_min_m[i],
            box.z_max_m[i],
        )
        for i in range(len(box))
    ]
    for c in range(n_col):
        for k in range(len(tan)):
            ref = reference_range(cols.origin[c], cols.direction[c], oz, tan[k], wall_rows, ref_cyl, ref_box)
            got = hits.range_h_m[c, k]
            assert (math.isinf(ref) and math.isinf(got)) or got == pytest.approx(ref, rel=1e-9, abs=1e-9), (
                c,
                k,
            )


def test_lidar_config_tables_reject_unknown_keys_and_bad_agents() -> None:
    row = {
        "sensor_id": "roof",
        "x_m": 1.0,
        "y_m": 0.0,
        "z_m": 2.0,
        "yaw_rad": 0.0,
        "elevations_deg": [-10, 0, 10],
    }
    (spec,) = lidar_specs_from_config([row])
    assert spec.elevations_deg == (-10.0, 0.0, 10.0)
    with pytest.raises(ConfigError, match="unknown"):
        lidar_specs_from_config([{**row, "rpm": 600}])
    with pytest.raises(ConfigError, match="min_range_m < max_range_m"):
        lidar_specs_from_config([{**row, "max_range_m": 0.2}])
    nan_car = Agent(
        id=3,
        cls=ObjectClass.CAR,
        x_m=float("nan"),
        y_m=0.0,
        yaw_rad=0.0,
        speed_mps=0.0,
        length_m=4.0,
        width_m=2.0,
        rcs_dbsm=0.0,
    )
    with pytest.raises(MessageError, match="agent 3"):
        DynamicObjects.from_agents([nan_car])
