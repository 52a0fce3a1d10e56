"""The scene of the perception quality benchmark, and its ground truth in the vehicle's base frame.

``benchmarks/perception_quality.py`` adds these road users to the default campus service and reads the
truth through these helpers for scoring only; the pipeline sees the map lines as the stack gives them.
"""

from __future__ import annotations

import math

import numpy as np
from tests.perception import quality_scoring as qs

from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.hdmap.model import HDMap
from lastmile.perception.map_curbs import MapCurbIndex
from lastmile.sim.agents import Agent
from lastmile.sim.lidar_ground import bank_height_m
from lastmile.sim.raw_sensors import RawSensorRig
from lastmile.sim.sensors import RCS_DBSM
from lastmile.sim.world import World

CURB_AHEAD_M = 28.0  # with the 2 m behind: the curb stage's 30 m (s_max_m) covers it all
EXTRA_ID0 = 10_000


def extra_agents(hdmap: HDMap, route_xy: np.ndarray, spacing_m: float, seed: int) -> list[Agent]:
    """Standing pedestrians and geese beside every mapped curb near the route (seeded).

    Every ``spacing_m`` along each curb within 12 m of the route, in turn: a pedestrian on the
    verge 0.6-2.5 m behind the curb, a goose on the road 1.5-2.5 m from the curb, a car parked
    along the curb (centre 1.1-1.4 m out), a pedestrian on the road 0.4-1.2 m from the curb
    (stepping off the kerb), a goose on the road again. Geese stand
    on the road because the simulator puts every road user's feet at z = 0: on a 0.15 m sidewalk a
    0.4 m goose would stand only 0.25 m proud; on the road it is the WATonoBus case (a goose near
    the curb). Positions whose side is not as intended (drivable or not) are skipped.
    """
    rng = np.random.default_rng(seed)
    agents: list[Agent] = []
    k = 0
    for curb in hdmap.curbs:
        s_all = np.arange(spacing_m / 2.0, curb.length_m, spacing_m)
        if len(s_all) == 0:
            continue
        pts = curb.points_at(s_all)
        near = np.min(np.hypot(*(pts[:, None, :] - route_xy[None, :, :]).transpose(2, 0, 1)), axis=1) < 12.0
        for s, p in zip(s_all[near], pts[near], strict=True):
            h = curb.heading_at(float(s))
            normal = np.array([-math.sin(h), math.cos(h)])
            # Toward the road: the side that is drivable half a metre out.
            road_side = 1.0 if hdmap.is_drivable((p + 0.5 * normal)[None])[0] else -1.0
            kind = k % 5
            goose, car = kind in (1, 4), kind == 2
            if kind == 0:
                off = -rng.uniform(0.6, 2.5)
            elif goose:
                off = rng.uniform(1.5, 2.5)
            elif car:
                off = rng.uniform(1.1, 1.4)
            else:
                off = rng.uniform(0.4, 1.2)
            xy = p + road_side * off * normal
            k += 1
            if bool(hdmap.is_drivable(xy[None])[0]) != (off > 0):
                continue
            cls = ObjectClass.ANIMAL if goose else ObjectClass.CAR if car else ObjectClass.PEDESTRIAN
            yaw = h + rng.normal(0.0, 0.05) if car else rng.uniform(-math.pi, math.pi)
            agents.append(
                Agent(
                    id=EXTRA_ID0 + k,
                    cls=cls,
                    x_m=float(xy[0]),
                    y_m=float(xy[1]),
                    yaw_rad=float(yaw),
                    speed_mps=0.0,
                    length_m=4.5 if car else 0.5,
                    width_m=1.8 if car else 0.3 if goose else 0.5,
                    rcs_dbsm=RCS_DBSM[cls],
                )
            )
    return agents


def curb_ahead(hdmap: HDMap, pose: SE2, side: str) -> np.ndarray | None:
    """The nearest mapped curb on the vehicle's ``side`` ("right" or "left"), as an (M, 2)
    map-frame polyline with the road on its left (the right curb in the driving direction, the
    left one against it), covering 2 m behind the base origin to 28 m ahead; None where no such
    curb runs beside the vehicle (within 9 m) for at least 10 m."""
    best: tuple[float, np.ndarray] | None = None
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    want = -1.0 if side == "right" else 1.0
    for curb in hdmap.curbs:
        f = curb.project(pose.x_m, pose.y_m)
        if abs(f.d_m) > 9.0:
            continue
        px, py, heading = curb.point_at(f.s_m)
        lateral = -(px - pose.x_m) * s + (py - pose.y_m) * c  # left of the vehicle, base frame
        if not 0.5 <= want * lateral <= 9.0:
            continue
        along_dir = math.cos(heading - pose.yaw_rad)
        if abs(along_dir) < 0.85:
            continue
        sign = 1.0 if along_dir > 0 else -1.0
        s_lo = float(np.clip(f.s_m - sign * 2.0, 0.0, curb.length_m))
        s_hi = float(np.clip(f.s_m + sign * CURB_AHEAD_M, 0.0, curb.length_m))
        if abs(s_hi - s_lo) < 10.0:
            continue
        xy = curb.sub(s_lo, s_hi, 2.0)  # in the driving direction
        if side == "left":
            xy = xy[::-1]  # road on its left: walk it against the driving direction
        if best is None or abs(lateral) < best[0]:
            best = (abs(lateral), xy)
    return None if best is None else best[1]


_CURB_INDEX: dict[int, MapCurbIndex] = {}


def curb_lines_near(hdmap: HDMap, pose: SE2, reach_m: float = 45.0) -> list[np.ndarray]:
    """Every mapped curb line (any side) within ``reach_m`` of the vehicle, base frame: what the
    stack gives the pipeline's curb-side stage (``MapCurbIndex.lines_near``, the same code)."""
    index = _CURB_INDEX.get(id(hdmap))
    if index is None:
        index = _CURB_INDEX[id(hdmap)] = MapCurbIndex(hdmap)
    return index.lines_near(pose, reach_m)


def clear_of_ego(agent: Agent, world: World, clearance_m: float = 1.0) -> bool:
    cx, cy = world.ego_centre()
    g = world.geometry
    ego = np.array([[cx, cy, world.ego.state.yaw_rad, g.length_m, g.width_m]])
    corners = agent.radius_m
    return float(qs.footprint_distance_m([[agent.x_m, agent.y_m]], ego)[0, 0]) > corners + clearance_m


def ground_z_m(rig: RawSensorRig, xy_m: np.ndarray) -> np.ndarray:
    """(M,) simulated ground height at map points: 0 on the road (plus snow lying there), the curb
    height elsewhere."""
    scene, w = rig.lidar.scene, rig.lidar.weather
    if scene.ground is None or len(xy_m) == 0:
        return np.zeros(len(xy_m))
    road = scene.ground.is_road(xy_m[:, 0], xy_m[:, 1])
    snow = np.zeros(len(xy_m))
    if w.snow_on_road:
        dist = scene.ground.curb_distance_m(xy_m[:, 0], xy_m[:, 1])
        snow = bank_height_m(dist, scene.curb_height_m, w.snow_bank_width_m, w.snow_cover_lane_m)
    return np.where(road, snow, scene.curb_height_m)


def boxes_in_base(agents: list[Agent], pose: SE2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M,) ids, (M,) classes and (M, 5) footprints ``x y yaw length width`` in the true base frame."""
    inv = pose.inverse()
    ids = np.array([a.id for a in agents], dtype=np.int64)
    cls = np.array([int(a.cls) for a in agents], dtype=np.int64)
    boxes = np.zeros((len(agents), 5))
    if agents:
        xy = inv.apply_points(np.array([[a.x_m, a.y_m] for a in agents]))
        boxes[:, :2] = xy
        boxes[:, 2] = [a.yaw_rad - pose.yaw_rad for a in agents]
        boxes[:, 3] = [a.length_m for a in agents]
        boxes[:, 4] = [a.width_m for a in agents]
    return ids, cls, boxes
