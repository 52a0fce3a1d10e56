"""What a simulated LiDAR ray can hit: the static campus from the HD map and the moving road users.

Every solid is a vertical prism standing on the ground, so a ray is intersected in the plane first
(one 2D test per azimuth column) and only then per laser channel (a height test):

- thin walls (``Segments``): building facades (height from the map), curb faces (the curb height
  between road and sidewalk), sign plates (retro-reflective) on their posts;
- ``Cylinders``: light poles, sign posts and pedestrians;
- ``Boxes``: cars, cyclists, geese and the shuttle's own body (whose returns the driver crops).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.object_class import ObjectClass
from lastmile.hdmap.model import HDMap
from lastmile.sim.agents import Agent
from lastmile.sim.lidar_ground import GroundRaster


class PointLabel(IntEnum):
    """What a simulated return came from (ground truth for benchmarks; never given to the stack)."""

    ROAD = 0
    SIDEWALK = 1
    CURB = 2
    SNOW = 3  # snow bank or snow lying on the lane
    BUILDING = 4
    POLE = 5
    SIGN = 6
    OBJECT = 7  # a road user: see the object id and class columns
    WEATHER_NOISE = 8  # a raindrop or snowflake
    EGO = 9  # the shuttle's own body (cropped before output)


# Diffuse reflectivity at 905 nm (0..1) by surface; "retro" surfaces return most of the beam
# whatever the incidence. Values are typical published NIR reflectivities: asphalt ~0.1, concrete
# ~0.25-0.35, painted car bodies ~0.3, clothing ~0.2-0.4, fresh snow ~0.8.
REFLECTIVITY = {
    PointLabel.ROAD: 0.10,
    PointLabel.SIDEWALK: 0.25,
    PointLabel.CURB: 0.30,
    PointLabel.SNOW: 0.80,
    PointLabel.BUILDING: 0.35,
    PointLabel.POLE: 0.40,
    PointLabel.SIGN: 0.95,
    PointLabel.EGO: 0.30,
}
CLASS_REFLECTIVITY = {
    ObjectClass.CAR: 0.30,
    ObjectClass.PEDESTRIAN: 0.25,
    ObjectClass.CYCLIST: 0.30,
    ObjectClass.ANIMAL: 0.20,  # feathers: dark, diffuse
    ObjectClass.UNKNOWN: 0.25,
}
CLASS_HEIGHT_M = {
    ObjectClass.CAR: 1.5,
    ObjectClass.PEDESTRIAN: 1.75,
    ObjectClass.CYCLIST: 1.7,
    ObjectClass.ANIMAL: 0.4,  # a Canada goose standing
    ObjectClass.UNKNOWN: 1.0,
}

CURB_HEIGHT_M = 0.15
POLE_RADIUS_M = 0.12
SIGN_POST_RADIUS_M = 0.04
SIGN_PLATE_HALF_HEIGHT_M = 0.3
NO_OBJECT = -1


@dataclass(frozen=True, slots=True, kw_only=True)
class Segments:
    """Thin vertical walls. Arrays have one row per wall.

    Attributes:
        p0, p1: (S, 2) float64 end points in the map frame (m).
        z_min_m, z_max_m: (S,) float64 bottom and top (m above the road).
        label: (S,) int8 :class:`PointLabel`.
        reflectivity: (S,) float64 in [0, 1]; retro: (S,) bool.
    """

    p0: np.ndarray
    p1: np.ndarray
    z_min_m: np.ndarray
    z_max_m: np.ndarray
    label: np.ndarray
    reflectivity: np.ndarray
    retro: np.ndarray

    def __len__(self) -> int:
        return len(self.p0)


@dataclass(frozen=True, slots=True, kw_only=True)
class Cylinders:
    """Vertical cylinders; moving ones carry their map-frame velocity at ``stamp`` of the objects.

    Attributes:
        centre: (C, 2) float64 (m); radius_m, z_min_m, z_max_m: (C,) float64.
        velocity: (C, 2) float64 over-ground velocity (m/s).
        label: (C,) int8; object_id: (C,) int64 (-1 for the static world); object_class: (C,) int8.
        reflectivity: (C,) float64; retro: (C,) bool.
    """

    centre: np.ndarray
    radius_m: np.ndarray
    z_min_m: np.ndarray
    z_max_m: np.ndarray
    velocity: np.ndarray
    label: np.ndarray
    object_id: np.ndarray
    object_class: np.ndarray
    reflectivity: np.ndarray
    retro: np.ndarray

    def __len__(self) -> int:
        return len(self.centre)


@dataclass(frozen=True, slots=True, kw_only=True)
class Boxes:
    """Oriented boxes standing on the ground.

    Attributes:
        centre: (B, 2) float64 footprint centre (m); yaw_rad: (B,) heading of the length axis.
        half_length_m, half_width_m, z_min_m, z_max_m: (B,) float64.
        velocity: (B, 2) float64 (m/s); label, object_id, object_class, reflectivity: as
            :class:`Cylinders`.
    """

    centre: np.ndarray
    yaw_rad: np.ndarray
    half_length_m: np.ndarray
    half_width_m: np.ndarray
    z_min_m: np.ndarray
    z_max_m: np.ndarray
    velocity: np.ndarray
    label: np.ndarray
    object_id: np.ndarray
    object_class: np.ndarray
    reflectivity: np.ndarray

    def __len__(self) -> int:
        return len(self.centre)


def _cylinders(rows: list[tuple[float, ...]]) -> Cylinders:
    """Rows: x, y, radius, z_min, z_max, vx, vy, label, object_id, class, reflectivity, retro."""
    a = np.array(rows, dtype=np.float64).reshape(-1, 12)
    return Cylinders(
        centre=a[:, 0:2].copy(),
        radius_m=a[:, 2].copy(),
        z_min_m=a[:, 3].copy(),
        z_max_m=a[:, 4].copy(),
        velocity=a[:, 5:7].copy(),
        label=a[:, 7].astype(np.int8),
        object_id=a[:, 8].astype(np.int64),
        object_class=a[:, 9].astype(np.int8),
        reflectivity=a[:, 10].copy(),
        retro=a[:, 11] > 0.5,
    )


def _boxes(rows: list[tuple[float, ...]]) -> Boxes:
    """Rows: x, y, yaw, half_length, half_width, z_min, z_max, vx, vy, label, object_id, class, refl."""
    a = np.array(rows, dtype=np.float64).reshape(-1, 13)
    return Boxes(
        centre=a[:, 0:2].copy(),
        yaw_rad=a[:, 2].copy(),
        half_length_m=a[:, 3].copy(),
        half_width_m=a[:, 4].copy(),
        z_min_m=a[:, 5].copy(),
        z_max_m=a[:, 6].copy(),
        velocity=a[:, 7:9].copy(),
        label=a[:, 9].astype(np.int8),
        object_id=a[:, 10].astype(np.int64),
        object_class=a[:, 11].astype(np.int8),
        reflectivity=a[:, 12].copy(),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class StaticLidarScene:
    """The campus as LiDAR primitives, built once per map (see :func:`static_scene`)."""

    segments: Segments
    cylinders: Cylinders
    ground: GroundRaster | None
    curb_height_m: float = CURB_HEIGHT_M


def build_static_scene(hdmap: HDMap, curb_height_m: float = CURB_HEIGHT_M) -> StaticLidarScene:
    """Facades, curb faces, sign plates, poles and the ground raster of ``hdmap``."""
    if not (math.isfinite(curb_height_m) and 0.0 <= curb_height_m <= 0.5):
        raise ConfigError(f"curb_height_m: expected a number in [0, 0.5] m, got {curb_height_m}")
    seg: list[tuple[float, ...]] = []
    cyl: list[tuple[float, ...]] = []

    def walls(xy: np.ndarray, z0: float, z1: float, label: PointLabel, retro: bool) -> None:
        for p, q in itertools.pairwise(xy):
            if math.dist(p, q) > 1e-6:
                seg.append((p[0], p[1], q[0], q[1], z0, z1, label, REFLECTIVITY[label], float(retro)))

    for lm in hdmap.landmarks:
        xy = np.asarray(lm.xy, dtype=float)
        if lm.kind == "building_facade":
            walls(xy, 0.0, lm.height_m, PointLabel.BUILDING, retro=False)
        elif lm.kind == "light_pole":
            x, y = xy[0]
            cyl.append((x, y, POLE_RADIUS_M, 0.0, lm.height_m, 0, 0, PointLabel.POLE, -1, 0, 0.4, 0))
        elif lm.kind == "sign":
            top = lm.height_m + SIGN_PLATE_HALF_HEIGHT_M
            walls(xy, lm.height_m - SIGN_PLATE_HALF_HEIGHT_M, top, PointLabel.SIGN, retro=True)
            x, y = xy.mean(axis=0)
            bottom = lm.height_m - SIGN_PLATE_HALF_HEIGHT_M
            # The post stands just behind the plate so the plate faces traffic unobstructed.
            cyl.append((x, y, SIGN_POST_RADIUS_M, 0.0, bottom, 0, 0, PointLabel.POLE, -1, 0, 0.4, 0))
    for curb in hdmap.curbs:
        walls(np.asarray(curb.xy_m, dtype=float), 0.0, curb_height_m, PointLabel.CURB, retro=False)
    a = np.array(seg, dtype=np.float64).reshape(-1, 9)
    segments = Segments(
        p0=a[:, 0:2].copy(),
        p1=a[:, 2:4].copy(),
        z_min_m=a[:, 4].copy(),
        z_max_m=a[:, 5].copy(),
        label=a[:, 6].astype(np.int8),
        reflectivity=a[:, 7].copy(),
        retro=a[:, 8] > 0.5,
    )
    return StaticLidarScene(
        segments=segments, cylinders=_cylinders(cyl), ground=GroundRaster(hdmap), curb_height_m=curb_height_m
    )


_SCENES: dict[int, tuple[HDMap, StaticLidarScene]] = {}


def static_scene(hdmap: HDMap) -> StaticLidarScene:
    """:func:`build_static_scene` cached per map object (building the ground raster takes ~1 s).

    Keyed by identity (maps are not hashable); the cache holds the map so the key stays valid.
    """
    hit = _SCENES.get(id(hdmap))
    if hit is None or hit[0] is not hdmap:
        if len(_SCENES) >= 4:
            _SCENES.pop(next(iter(_SCENES)))
        hit = (hdmap, build_static_scene(hdmap))
        _SCENES[id(hdmap)] = hit
    return hit[1]


@dataclass(frozen=True, slots=True, kw_only=True)
class DynamicObjects:
    """Road users at one instant, as LiDAR primitives (pedestrians as cylinders, the rest as boxes)."""

    boxes: Boxes
    cylinders: Cylinders

    @staticmethod
    def from_agents(agents: list[Agent]) -> DynamicObjects:
        """Active agents of the simulated world; heights and reflectivities by class."""
        boxes: list[tuple[float, ...]] = []
        cyl: list[tuple[float, ...]] = []
        for a in agents:
            if not a.active:
                continue
            values = (a.x_m, a.y_m, a.yaw_rad, a.speed_mps, a.length_m, a.width_m)
            if not all(math.isfinite(v) for v in values) or a.length_m <= 0 or a.width_m <= 0:
                raise MessageError(
                    f"agent {a.id}: expected a finite pose and speed and a positive footprint, got "
                    f"x={a.x_m}, y={a.y_m}, yaw={a.yaw_rad}, v={a.speed_mps}, {a.length_m} x {a.width_m} m"
                )
            height = CLASS_HEIGHT_M.get(a.cls, 1.0)
            refl = CLASS_REFLECTIVITY.get(a.cls, 0.25)
            vx, vy = a.vx_mps, a.vy_mps
            if a.cls == ObjectClass.PEDESTRIAN:
                r = 0.5 * max(a.length_m, a.width_m)
                cyl.append((a.x_m, a.y_m, r, 0.0, height, vx, vy, PointLabel.OBJECT, a.id, a.cls, refl, 0))
            else:
                boxes.append(
                    (
                        a.x_m,
                        a.y_m,
                        a.yaw_rad,
                        0.5 * a.length_m,
                        0.5 * a.width_m,
                        0.0,
                        height,
                        vx,
                        vy,
                        PointLabel.OBJECT,
                        a.id,
                        a.cls,
                        refl,
                    )
                )
        return DynamicObjects(boxes=_boxes(boxes), cylinders=_cylinders(cyl))

    @staticmethod
    def empty() -> DynamicObjects:
        return DynamicObjects(boxes=_boxes([]), cylinders=_cylinders([]))

    def with_box(
        self,
        *,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        length_m: float,
        width_m: float,
        height_m: float,
        label: PointLabel = PointLabel.OBJECT,
        object_id: int = NO_OBJECT,
        object_class: ObjectClass = ObjectClass.UNKNOWN,
        reflectivity: float = 0.3,
        vx_mps: float = 0.0,
        vy_mps: float = 0.0,
    ) -> DynamicObjects:
        """A copy with one more box (the shuttle's body, or a test fixture)."""
        row = (x_m, y_m, yaw_rad, length_m / 2, width_m / 2, 0.0, height_m, vx_mps, vy_mps)
        extra = _boxes([(*row, label, object_id, int(object_class), reflectivity)])
        b = self.boxes
        merged = Boxes(
            **{
                name: np.concatenate([getattr(b, name), getattr(extra, name)])
                for name in Boxes.__dataclass_fields__
            }
        )
        return DynamicObjects(boxes=merged, cylinders=self.cylinders)
