"""A model-free traffic-light detector: 2D housing boxes with a bulb state, from the sim's cameras.

Per camera frame, each mapped signal head is projected through the camera (pinhole, its mounting on
the shuttle) and kept when it is in front, facing the camera (within ``max_view_angle_rad``), inside
the image, closer than the weather-scaled range, at least ``min_height_px`` tall and not hidden behind
a road user nearer to the camera (the head's centre inside that road user's image box). A kept head is
detected with a probability that falls with its size, the weather and, for a dark housing, darkness;
its state is drawn from the detector's confusion matrix (rows: the state shown), whose off-diagonal
part grows with the weather's and the night's confusion factors. Box edges get pixel noise; a few
spurious boxes appear (Poisson). Frames are stamped at capture and delivered after ``latency_us``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.rng import component_rng
from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import (
    N_LIGHT_STATES,
    LightState,
    MapTrafficLight,
    TrafficLightDetections,
)
from lastmile.sim.camera import CAMERA_WEATHER, CameraScene, default_cameras
from lastmile.sim.traffic_signals import SignalController
from lastmile.sim.weather import Weather
from lastmile.sim.world import World

# What a traffic-light detector reports for each shown state (rows red, yellow, green, off): red and
# yellow are confused most (both warm), a lit bulb against the sun reads as off now and then.
DEFAULT_DETECTOR_CONFUSION = (
    (0.94, 0.04, 0.00, 0.02),
    (0.05, 0.91, 0.02, 0.02),
    (0.00, 0.02, 0.96, 0.02),
    (0.03, 0.02, 0.02, 0.93),
)


@dataclass(frozen=True, slots=True, kw_only=True)
class TrafficLightDetectorConfig:
    """The simulated detector's performance in clear daylight.

    Attributes:
        camera_ids: cameras the detector runs on (aUToronto runs it on the forward cameras).
        period_ticks: frame period in base ticks (10 ms ticks: 10 -> 10 Hz).
        latency_us: capture to delivery, inference included.
        max_range_m: heads farther away are not detected (scaled by the weather's range factor).
        max_view_angle_rad: heads whose lenses face more than this away from the camera show no bulb.
        min_height_px: housings lower than this in the image are not detected.
        detect_prob_lit, detect_prob_dark: chance of detecting a well-sized lit head / dark housing.
        confusion: (4, 4) ``P(detected | shown)``, rows red, yellow, green, off; rows sum to 1.
        night_dark_factor: detection multiplier of a dark housing in full darkness (it is a black box
            against a black sky); lit bulbs are as visible at night.
        night_confusion_factor: off-diagonal confusion multiplier in full darkness (bloom).
        false_positives_per_frame: mean (Poisson) spurious boxes (tail lights, signs, reflections).
        pixel_noise_px: standard deviation of each box edge.
    """

    camera_ids: tuple[str, ...] = ("front",)
    period_ticks: int = 10
    latency_us: int = 80_000
    max_range_m: float = 70.0
    max_view_angle_rad: float = math.radians(60.0)
    min_height_px: float = 10.0
    detect_prob_lit: float = 0.96
    detect_prob_dark: float = 0.85
    confusion: tuple[tuple[float, ...], ...] = DEFAULT_DETECTOR_CONFUSION
    night_dark_factor: float = 0.3
    night_confusion_factor: float = 2.0
    false_positives_per_frame: float = 0.02
    pixel_noise_px: float = 1.5

    def __post_init__(self) -> None:
        if self.period_ticks < 1 or self.latency_us < 0:
            raise ConfigError(
                "TrafficLightDetectorConfig: expected period_ticks >= 1 and latency_us >= 0, got "
                f"{self.period_ticks}, {self.latency_us}"
            )
        for name in ("max_range_m", "min_height_px", "pixel_noise_px", "false_positives_per_frame"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(
                    f"TrafficLightDetectorConfig.{name}: expected a finite number >= 0, got {v!r}"
                )
        for name in ("detect_prob_lit", "detect_prob_dark", "night_dark_factor"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"TrafficLightDetectorConfig.{name}: expected a probability, got {v!r}")
        c = np.asarray(self.confusion, dtype=float)
        if (
            c.shape != (N_LIGHT_STATES, N_LIGHT_STATES)
            or np.any(c < 0)
            or not np.allclose(c.sum(axis=1), 1.0)
        ):
            raise ConfigError(
                "TrafficLightDetectorConfig.confusion: expected a 4x4 matrix of non-negative rows summing "
                f"to 1, got {self.confusion}"
            )


def scaled_confusion(confusion: np.ndarray, factor: float) -> np.ndarray:
    """The confusion matrix with its off-diagonal part times ``factor`` (capped so rows stay valid)."""
    c = np.asarray(confusion, dtype=float).copy()
    off = c - np.diag(np.diag(c))
    scale = np.minimum(factor, 0.9 / np.maximum(off.sum(axis=1), 1e-12))  # keep >= 10 % on the diagonal
    off = off * scale[:, None]
    return np.asarray(off + np.diag(1.0 - off.sum(axis=1)))


class TrafficLightDetectorModel:
    """The simulated light detector on one camera.

    Args:
        camera: intrinsics and mounting on the shuttle.
        heads: the map's signal heads.
        weather: the run's weather.
        daylight: 1 by day, 0 at night.
        seed: the run seed; the stream is ``sensor.traffic_lights.<camera_id>``.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        heads: tuple[MapTrafficLight, ...],
        weather: Weather,
        daylight: float,
        seed: int,
        config: TrafficLightDetectorConfig | None = None,
    ) -> None:
        if not (isinstance(daylight, int | float) and 0.0 <= daylight <= 1.0):
            raise ConfigError(
                f"TrafficLightDetectorModel.daylight: expected a number in [0, 1], got {daylight!r}"
            )
        self.camera = camera
        self.heads = tuple(heads)
        self.config = config or TrafficLightDetectorConfig()
        self.effects = CAMERA_WEATHER[weather]
        self.daylight = float(daylight)
        dark = 1.0 - self.daylight
        self._confusion = scaled_confusion(
            np.asarray(self.config.confusion),
            self.effects.confusion_factor * (1.0 + dark * (self.config.night_confusion_factor - 1.0)),
        )
        self._rng = component_rng(seed, f"sensor.traffic_lights.{camera.camera_id}")
        self._table = np.array(
            [[h.x_m, h.y_m, h.z_m, h.facing_rad, h.width_m, h.height_m] for h in self.heads], dtype=np.float64
        ).reshape(-1, 6)

    def detect(
        self, map_from_base: SE2, shown: np.ndarray, scene: CameraScene, stamp: Stamp
    ) -> tuple[TrafficLightDetections, np.ndarray]:
        """Detections of one frame, and the (N,) head index behind each box (-1: false positive).

        Args:
            map_from_base: the shuttle's true pose at capture.
            shown: (H,) int LightState each head shows now (OFF between flashes or when dark).
            scene: the road users (for occlusion).
            stamp: capture time.
        """
        cam, cfg, fx, rng = self.camera, self.config, self.effects, self._rng
        shown = np.asarray(shown, dtype=np.int64)
        if shown.shape != (len(self.heads),):
            raise ConfigError(
                f"TrafficLightDetectorModel.detect: expected {len(self.heads)} shown states, "
                f"got {shown.shape}"
            )
        dark = 1.0 - self.daylight
        boxes: list[np.ndarray] = []
        states: list[int] = []
        scores: list[float] = []
        truth: list[int] = []
        for i, box, height_px in self._visible(map_from_base, scene):
            s = int(shown[i])
            p = (
                cfg.detect_prob_lit
                if s != LightState.OFF
                else cfg.detect_prob_dark * (1.0 - dark * (1.0 - cfg.night_dark_factor))
            )
            size = min(1.0, max(0.0, (height_px - cfg.min_height_px) / cfg.min_height_px))
            p *= fx.detect_factor * (0.6 + 0.4 * size)
            if rng.random() >= p:
                continue
            detected = int(rng.choice(N_LIGHT_STATES, p=self._confusion[s]))
            noisy = box + rng.normal(0.0, cfg.pixel_noise_px * fx.noise_factor, 4)
            noisy = np.array(
                [min(noisy[0], noisy[2] - 1.0), min(noisy[1], noisy[3] - 1.0), noisy[2], noisy[3]]
            )
            right = detected == s
            scores.append(float(np.clip(rng.normal(0.85 if right else 0.6, 0.08), 0.05, 0.99)))
            boxes.append(noisy)
            states.append(detected)
            truth.append(i)
        for _ in range(int(rng.poisson(cfg.false_positives_per_frame * fx.false_positive_factor))):
            h = float(rng.uniform(cfg.min_height_px, 60.0))
            u = float(rng.uniform(0.0, cam.width_px - 0.4 * h))
            v = float(rng.uniform(0.0, 0.6 * cam.height_px))
            boxes.append(np.array([u, v, u + 0.4 * h, v + h]))
            states.append(int(rng.integers(0, N_LIGHT_STATES)))
            scores.append(float(rng.uniform(0.2, 0.6)))
            truth.append(-1)
        dets = TrafficLightDetections(
            stamp=stamp,
            camera_id=cam.camera_id,
            boxes=np.array(boxes, dtype=np.float64).reshape(-1, 4),
            states=np.array(states, dtype=np.int64),
            scores=np.array(scores, dtype=np.float64),
        )
        return dets, np.array(truth, dtype=np.int64)

    def _visible(self, map_from_base: SE2, scene: CameraScene) -> list[tuple[int, np.ndarray, float]]:
        """(head index, housing box, box height px) of the heads the camera can see."""
        cam, cfg = self.camera, self.config
        t = self._table
        if len(t) == 0:
            return []
        base_from_map = map_from_base.inverse()
        pts = np.column_stack([base_from_map.apply_points(t[:, :2]), t[:, 2]])
        pc = cam.to_camera(pts)
        cx, cy = map_from_base.apply(cam.x_m, cam.y_m)
        dx, dy = cx - t[:, 0], cy - t[:, 1]
        dist = np.sqrt(dx * dx + dy * dy + (cam.z_m - t[:, 2]) ** 2)
        cos_view = (np.cos(t[:, 3]) * dx + np.sin(t[:, 3]) * dy) / np.maximum(np.hypot(dx, dy), 1e-9)
        ok = (pc[:, 2] > 1.0) & (dist <= cfg.max_range_m * self.effects.range_factor)
        ok &= cos_view >= math.cos(cfg.max_view_angle_rad)
        out = []
        # The road users are projected only once a head is in the picture (most frames have none).
        blockers: list[tuple[float, float, float, float, float]] | None = None
        for i in np.flatnonzero(ok).tolist():
            z = pc[i, 2]
            ((u, v),) = cam.pixels_from_camera(pc[i : i + 1])
            hw, hh = 0.5 * cam.fx_px * t[i, 4] / z, 0.5 * cam.fy_px * t[i, 5] / z
            box = np.array([u - hw, v - hh, u + hw, v + hh])
            if (
                box[0] < 0
                or box[1] < 0
                or box[2] > cam.width_px
                or box[3] > cam.height_px
                or 2 * hh < cfg.min_height_px
            ):
                continue
            if blockers is None:
                blockers = self._blockers(map_from_base, scene)
            if any(b[4] < z and b[0] <= u <= b[2] and b[1] <= v <= b[3] for b in blockers):
                continue
            out.append((i, box, 2 * hh))
        return out

    def _blockers(
        self, map_from_base: SE2, scene: CameraScene
    ) -> list[tuple[float, float, float, float, float]]:
        """Image boxes (u0, v0, u1, v1, nearest depth) of the road users in front of the camera."""
        cam = self.camera
        rows = np.asarray(scene.boxes, dtype=np.float64).reshape(-1, 8)
        if len(rows) == 0:
            return []
        base_from_map = map_from_base.inverse()
        out = []
        for x, y, yaw, length, width, height, _, _ in rows.tolist():
            c, s = math.cos(yaw), math.sin(yaw)
            corners = [
                (x + c * a - s * b, y + s * a + c * b)
                for a in (-length / 2, length / 2)
                for b in (-width / 2, width / 2)
            ]
            xy = base_from_map.apply_points(np.array(corners))
            pts = np.vstack([np.column_stack([xy, np.zeros(4)]), np.column_stack([xy, np.full(4, height)])])
            pc = cam.to_camera(pts)
            if np.any(pc[:, 2] <= 0.2):  # behind the camera (or straddling it): not in the picture
                continue
            uv = cam.pixels_from_camera(pc)
            out.append(
                (
                    float(uv[:, 0].min()),
                    float(uv[:, 1].min()),
                    float(uv[:, 0].max()),
                    float(uv[:, 1].max()),
                    float(pc[:, 2].min()),
                )
            )
        return out


class TrafficLightCameraRig:
    """The light detectors on the shuttle's cameras, fed the signals' true states each frame.

    Args:
        world: the simulated world (map heads, ego pose, road users, weather).
        signals: the signal controller (what every head shows).
        seed: the run seed.
        tick_us: the base tick.
        daylight: 1 by day, 0 at night.
        cameras: the shuttle's cameras (default :func:`lastmile.sim.camera.default_cameras`); the
            detector runs on those named in ``config.camera_ids``.
    """

    def __init__(
        self,
        world: World,
        signals: SignalController,
        seed: int,
        tick_us: int,
        daylight: float = 1.0,
        cameras: tuple[PinholeCamera, ...] | None = None,
        config: TrafficLightDetectorConfig | None = None,
    ) -> None:
        self.world = world
        self.signals = signals
        self.tick_us = tick_us
        self.config = config or TrafficLightDetectorConfig()
        self.heads = world.hdmap.traffic_lights
        available = {c.camera_id: c for c in (cameras or default_cameras(world.geometry))}
        missing = [cid for cid in self.config.camera_ids if cid not in available]
        if missing:
            raise ConfigError(
                f"TrafficLightDetectorConfig.camera_ids: expected cameras among {sorted(available)}, "
                f"got {missing}"
            )
        self.cameras = tuple(available[cid] for cid in self.config.camera_ids)
        self.detectors = tuple(
            TrafficLightDetectorModel(cam, self.heads, world.weather, daylight, seed, self.config)
            for cam in self.cameras
        )
        self.last_truth: dict[str, np.ndarray] = {}

    def shown(self, t_s: float) -> np.ndarray:
        """(H,) LightState each head shows at ``t_s``."""
        return np.array([int(self.signals.state(h.signal_id, t_s)) for h in self.heads], dtype=np.int64)

    def sample(self, tick: int) -> list[tuple[TrafficLightDetections, int]]:
        """Frames captured at ``tick``: (detections, latency from capture to delivery in us)."""
        if not self.heads or tick % self.config.period_ticks:
            return []
        now = tick * self.tick_us
        s = self.world.ego.state
        pose = SE2(s.x_m, s.y_m, s.yaw_rad)
        scene = CameraScene.from_agents(pose, self.world.agents)
        shown = self.shown(now / 1e6)
        out = []
        for det in self.detectors:
            frame, truth = det.detect(pose, shown, scene, Stamp(now))
            self.last_truth[det.camera.camera_id] = truth
            out.append((frame, self.config.latency_us))
        return out
