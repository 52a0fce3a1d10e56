"""A model-free camera detector: 2D boxes with class and score for the road users a camera can see.

No image is rendered. Each road user's 3D box is projected through the camera's K [R|t]; what is
behind the camera or outside the image is not seen, boxes are clipped at the image border
(truncation), nearer objects hide farther ones (a coarse depth-ordered raster), and small, far,
mostly hidden objects are dropped. What remains is detected with a probability (and scored) that
falls with size, visibility, weather and darkness; classes are sometimes confused, edges are noisy
and false boxes appear. It satisfies :class:`lastmile.core.camera_model.CameraDetector`, so a real
network taking an image can replace it without changing its consumers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.rng import component_rng
from lastmile.core.sensor_frames import CameraDetections
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.agents import Agent
from lastmile.sim.lidar_scene import CLASS_HEIGHT_M
from lastmile.sim.weather import Weather

_NEAR_M = 0.2
_RASTER_PX = 8  # occlusion raster cell (pixels)
# Box edges of a unit cube's 8 corners (bottom 0-3, top 4-7), for clipping at the near plane.
_EDGES = np.array(
    [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]]
)


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraWeather:
    """How weather degrades the detector (multipliers on the clear-day values)."""

    detect_factor: float
    range_factor: float
    false_positive_factor: float
    noise_factor: float
    confusion_factor: float


# Rain streaks and snow on the lens cost a few per cent of detections; fog cuts contrast with range.
CAMERA_WEATHER = {
    Weather.CLEAR: CameraWeather(
        detect_factor=1.0, range_factor=1.0, false_positive_factor=1.0, noise_factor=1.0, confusion_factor=1.0
    ),
    Weather.RAIN: CameraWeather(
        detect_factor=0.95,
        range_factor=0.85,
        false_positive_factor=2.0,
        noise_factor=1.3,
        confusion_factor=1.5,
    ),
    Weather.SNOW: CameraWeather(
        detect_factor=0.9,
        range_factor=0.75,
        false_positive_factor=3.0,
        noise_factor=1.5,
        confusion_factor=2.0,
    ),
    Weather.FOG: CameraWeather(
        detect_factor=0.9, range_factor=0.5, false_positive_factor=1.5, noise_factor=1.3, confusion_factor=1.5
    ),
}


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraDetectorConfig:
    """Performance of the simulated detector in clear daylight (YOLO-class detector on a 3 MP camera).

    Attributes:
        detect_prob: per-class chance of detecting a large, fully visible object.
        min_height_px: boxes lower than this (after clipping) are not detected.
        max_range_m: nothing farther is detected (scaled by the weather's range factor).
        min_visible_fraction: objects less visible than this (truncation x occlusion) are dropped.
        confusion_prob: chance a detection gets a wrong (plausible) class.
        false_positives_per_frame: mean (Poisson) spurious boxes per frame.
        pixel_noise_px: standard deviation of each box edge, plus ``pixel_noise_rel`` of the box size.
        night_detect_factor: detection probability multiplier in full darkness (``daylight`` 0).
        latency_us: capture to delivery (the detector's inference time included).
    """

    detect_prob: dict[ObjectClass, float] = field(
        default_factory=lambda: {
            ObjectClass.CAR: 0.98,
            ObjectClass.PEDESTRIAN: 0.96,
            ObjectClass.CYCLIST: 0.94,
            ObjectClass.ANIMAL: 0.85,
            ObjectClass.UNKNOWN: 0.5,
        }
    )
    min_height_px: float = 14.0
    max_range_m: float = 80.0
    min_visible_fraction: float = 0.3
    confusion_prob: float = 0.02
    false_positives_per_frame: float = 0.05
    pixel_noise_px: float = 1.5
    pixel_noise_rel: float = 0.02
    night_detect_factor: float = 0.6
    latency_us: int = 60_000

    def __post_init__(self) -> None:
        for name in (
            "min_height_px",
            "max_range_m",
            "min_visible_fraction",
            "confusion_prob",
            "false_positives_per_frame",
            "pixel_noise_px",
            "pixel_noise_rel",
            "night_detect_factor",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ConfigError(
                    f"CameraDetectorConfig.{name}: expected a finite number >= 0, got {value!r}"
                )
        for name in ("min_visible_fraction", "confusion_prob", "night_detect_factor"):
            if getattr(self, name) > 1.0:
                raise ConfigError(
                    f"CameraDetectorConfig.{name}: expected a probability <= 1, got {getattr(self, name)}"
                )
        for cls, p in self.detect_prob.items():
            if not 0.0 <= p <= 1.0:
                raise ConfigError(f"CameraDetectorConfig.detect_prob[{cls.name}]: expected 0..1, got {p}")


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraScene:
    """What the camera looks at: the shuttle's pose and the road users' 3D boxes (map frame).

    Attributes:
        map_from_base: the shuttle's pose at capture.
        boxes: (N, 8) float64 rows x_m, y_m, yaw_rad, length_m, width_m, height_m, class_id, object_id.
    """

    map_from_base: SE2
    boxes: np.ndarray

    @staticmethod
    def from_agents(map_from_base: SE2, agents: list[Agent]) -> CameraScene:
        rows = [
            (
                a.x_m,
                a.y_m,
                a.yaw_rad,
                a.length_m,
                a.width_m,
                CLASS_HEIGHT_M.get(a.cls, 1.0),
                float(a.cls),
                float(a.id),
            )
            for a in agents
            if a.active
        ]
        return CameraScene(map_from_base=map_from_base, boxes=np.array(rows, dtype=np.float64).reshape(-1, 8))


def default_cameras(geometry: VehicleGeometry) -> tuple[PinholeCamera, ...]:
    """A front and a rear 2048 x 1536 camera (3.2 MP, as WATonoBus' Basler units), 70 deg wide."""
    return (
        PinholeCamera.from_fov(
            "front",
            2048,
            1536,
            70.0,
            geometry.front_from_rear_axle_m - 0.2,
            0.0,
            2.2,
            pitch_rad=math.radians(5.0),
        ),
        PinholeCamera.from_fov(
            "rear",
            2048,
            1536,
            70.0,
            -geometry.rear_overhang_m + 0.2,
            0.0,
            2.2,
            yaw_rad=math.pi,
            pitch_rad=math.radians(5.0),
        ),
    )


# Plausible confusions: what a detector mistakes each class for.
_CONFUSED_AS = {
    ObjectClass.CAR: ObjectClass.UNKNOWN,
    ObjectClass.PEDESTRIAN: ObjectClass.CYCLIST,
    ObjectClass.CYCLIST: ObjectClass.PEDESTRIAN,
    ObjectClass.ANIMAL: ObjectClass.UNKNOWN,
    ObjectClass.UNKNOWN: ObjectClass.PEDESTRIAN,
}


class CameraDetectorModel:
    """The simulated detector of one camera (see the module docstring).

    Args:
        camera: intrinsics and mounting.
        weather: the run's weather.
        daylight: 1 in daylight, 0 at night (street lights only); in between at dusk.
        seed: the run seed; the stream is ``sensor.camera.<camera_id>``.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        weather: Weather,
        daylight: float,
        seed: int,
        config: CameraDetectorConfig | None = None,
    ) -> None:
        if not isinstance(weather, Weather):
            raise ConfigError(f"CameraDetectorModel.weather: expected a Weather, got {weather!r}")
        if not (isinstance(daylight, int | float) and 0.0 <= daylight <= 1.0):
            raise ConfigError(f"CameraDetectorModel.daylight: expected a number in [0, 1], got {daylight!r}")
        self.camera = camera
        self.camera_id = camera.camera_id
        self.config = config or CameraDetectorConfig()
        self.effects = CAMERA_WEATHER[weather]
        self.daylight = float(daylight)
        self._rng = component_rng(seed, f"sensor.camera.{camera.camera_id}")
        self._rot, self._t = camera.rotation, camera.translation

    def detect(self, observation: CameraScene, stamp: Stamp) -> CameraDetections:
        """Boxes for ``observation`` (a :class:`CameraScene`) captured at ``stamp``."""
        return self.detect_with_truth(observation, stamp)[0]

    def detect_with_truth(self, scene: CameraScene, stamp: Stamp) -> tuple[CameraDetections, np.ndarray]:
        """As :meth:`detect`, with the (N,) object id behind each box (-1 for a false positive)."""
        if not isinstance(scene, CameraScene):
            raise ConfigError(
                f"CameraDetectorModel.detect: expected a CameraScene, got {type(scene).__name__}"
            )
        cam, cfg, fx, rng = self.camera, self.config, self.effects, self._rng
        dark = 1.0 - self.daylight
        light = 1.0 - dark * (1.0 - cfg.night_detect_factor)
        candidates = self._visible_boxes(scene)
        rows: list[tuple[float, float, float, float, float, float]] = []
        ids: list[int] = []
        for u0, v0, u1, v1, visible, cls, oid, height_px in candidates:
            c = ObjectClass(int(cls))
            # Small boxes are found less often: certain from twice the minimum height (darker: larger).
            min_h = cfg.min_height_px * (1.0 + dark)
            size = min(1.0, max(0.0, (height_px - min_h) / min_h))
            p = (
                cfg.detect_prob.get(c, 0.5)
                * fx.detect_factor
                * light
                * (0.5 + 0.5 * size)
                * (0.6 + 0.4 * visible)
            )
            if rng.random() >= p:
                continue
            if rng.random() < min(1.0, cfg.confusion_prob * fx.confusion_factor * (1.0 + dark)):
                c = _CONFUSED_AS[c]
            sigma = (cfg.pixel_noise_px + cfg.pixel_noise_rel * height_px) * fx.noise_factor * (1.0 + dark)
            e = rng.normal(0.0, sigma, 4)
            box = (
                min(max(u0 + e[0], 0.0), cam.width_px),
                min(max(v0 + e[1], 0.0), cam.height_px),
                min(max(u1 + e[2], 0.0), cam.width_px),
                min(max(v1 + e[3], 0.0), cam.height_px),
            )
            if box[2] - box[0] < 1.0 or box[3] - box[1] < 1.0:
                continue
            score = float(np.clip(0.3 + 0.7 * p + rng.normal(0.0, 0.05), 0.05, 0.99))
            rows.append((*box, float(c), score))
            ids.append(int(oid))
        for _ in range(
            int(rng.poisson(cfg.false_positives_per_frame * fx.false_positive_factor * (1.0 + dark)))
        ):
            h = float(rng.uniform(cfg.min_height_px, 150.0))
            w = h * float(rng.uniform(0.4, 1.6))
            u = float(rng.uniform(0.0, cam.width_px - w))
            v = float(rng.uniform(cam.height_px * 0.3, cam.height_px - h))
            cls_fp = float(rng.choice([ObjectClass.PEDESTRIAN, ObjectClass.CAR, ObjectClass.UNKNOWN]))
            rows.append((u, v, u + w, v + h, cls_fp, float(rng.uniform(0.25, 0.55))))
            ids.append(-1)
        boxes = np.array(rows, dtype=np.float32).reshape(-1, 6)
        return CameraDetections(stamp=stamp, camera_id=cam.camera_id, boxes=boxes), np.array(
            ids, dtype=np.int64
        )

    def _visible_boxes(self, scene: CameraScene) -> list[tuple[float, ...]]:
        """(u0, v0, u1, v1, visible_fraction, class, id, height_px) of the objects left after the geometry
        limits (behind, outside, too far, too small, too hidden), nearest first."""
        cam, cfg = self.camera, self.config
        boxes = np.asarray(scene.boxes, dtype=np.float64).reshape(-1, 8)
        if len(boxes) == 0:
            return []
        base_from_map = scene.map_from_base.inverse()
        max_range = cfg.max_range_m * self.effects.range_factor
        projected: list[tuple[float, float, float, float, float, float, float, float]] = []
        # Objects whose centre lies clearly beyond the range (a metre of margin for the rounding
        # of the two frames) fail the exact test below anyway: skipped before their corners.
        cam_xy = scene.map_from_base.apply_points(np.array([[cam.x_m, cam.y_m]]))[0]
        boxes = boxes[np.hypot(boxes[:, 0] - cam_xy[0], boxes[:, 1] - cam_xy[1]) <= max_range + 1.0]
        for x, y, yaw, length, width, height, cls, oid in boxes:
            corners = _corners(x, y, yaw, length, width, height)
            xy = base_from_map.apply_points(corners[:, :2])
            pc = np.column_stack([xy, corners[:, 2]]) @ self._rot.T + self._t
            depth = pc[:, 2]
            if depth.max() < _NEAR_M or float(np.hypot(*(xy.mean(axis=0) - (cam.x_m, cam.y_m)))) > max_range:
                continue
            if depth.min() < _NEAR_M:
                # Keep the part in front of the camera: corners ahead plus the near-plane crossings.
                a, b = pc[_EDGES[:, 0]], pc[_EDGES[:, 1]]
                cross = (a[:, 2] - _NEAR_M) * (b[:, 2] - _NEAR_M) < 0
                s = (_NEAR_M - a[cross, 2]) / (b[cross, 2] - a[cross, 2])
                pc = np.vstack([pc[depth >= _NEAR_M], a[cross] + s[:, None] * (b[cross] - a[cross])])
            uv = cam.pixels_from_camera(pc)
            u0, v0 = uv.min(axis=0)
            u1, v1 = uv.max(axis=0)
            cu0, cv0 = max(u0, 0.0), max(v0, 0.0)
            cu1, cv1 = min(u1, float(cam.width_px)), min(v1, float(cam.height_px))
            if cu1 <= cu0 or cv1 <= cv0:
                continue  # outside the field of view
            full = (u1 - u0) * (v1 - v0)
            truncation = (cu1 - cu0) * (cv1 - cv0) / max(full, 1e-9)
            projected.append((float(max(depth.min(), _NEAR_M)), cu0, cv0, cu1, cv1, truncation, cls, oid))
        projected.sort(key=lambda r: r[0])
        covered = np.zeros((cam.height_px // _RASTER_PX + 1, cam.width_px // _RASTER_PX + 1), dtype=bool)
        out: list[tuple[float, ...]] = []
        for _, u0, v0, u1, v1, truncation, cls, oid in projected:
            r0, r1 = int(v0 // _RASTER_PX), math.ceil(v1 / _RASTER_PX)
            c0, c1 = int(u0 // _RASTER_PX), math.ceil(u1 / _RASTER_PX)
            cells = covered[r0:r1, c0:c1]
            unoccluded = 1.0 - float(cells.mean()) if cells.size else 0.0
            cells[:] = True
            visible = truncation * unoccluded
            if visible < cfg.min_visible_fraction or (v1 - v0) < cfg.min_height_px:
                continue
            out.append((u0, v0, u1, v1, visible, cls, oid, v1 - v0))
        return out


def _corners(x: float, y: float, yaw: float, length: float, width: float, height: float) -> np.ndarray:
    """(8, 3) box corners, bottom four then top four, in the map frame."""
    c, s = math.cos(yaw), math.sin(yaw)
    lx = np.array([1.0, -1.0, -1.0, 1.0]) * length / 2.0
    ly = np.array([1.0, 1.0, -1.0, -1.0]) * width / 2.0
    px, py = x + c * lx - s * ly, y + s * lx + c * ly
    bottom = np.column_stack([px, py, np.zeros(4)])
    top = np.column_stack([px, py, np.full(4, height)])
    return np.vstack([bottom, top])
