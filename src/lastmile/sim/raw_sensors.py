"""Raw LiDAR sweeps and camera detections from the simulated world, timed as the real sensors.

An adapter for the integrator: call :meth:`RawSensorRig.sample` every base tick after the world has
advanced; it keeps the shuttle's pose history (so each sweep is cast along the path actually driven
during it) and returns the frames due at this tick with their latency from capture to delivery,
ready for the sensor suite's delivery queue.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.sim.camera import CameraDetectorConfig, CameraDetectorModel, CameraScene, default_cameras
from lastmile.sim.lidar import LidarSimulator, LidarTruth
from lastmile.sim.lidar_rig import EgoTrack, LidarSpec, default_lidar_rig
from lastmile.sim.lidar_scene import DynamicObjects, static_scene
from lastmile.sim.lidar_weather import lidar_weather
from lastmile.sim.world import World


class RawSensorRig:
    """The shuttle's LiDARs and cameras over a :class:`World`.

    Args:
        world: the simulated world (its map, weather, ego and agents are read).
        seed: the run seed.
        tick_us: the base tick.
        lidar_specs: the LiDAR rig (default :func:`lastmile.sim.lidar.default_lidar_rig`).
        cameras: the cameras (default front and rear).
        daylight: 1 by day, 0 at night (cameras only: LiDAR does not need light).
        weather_intensity: 0..2 scale of the precipitation / fog terms (1: reference event).
        snow_cover_lane_m: lane width next to the curb under snow (a scenario setting).
        camera_period_ticks: camera frame period in base ticks (10 ms ticks: 10 -> 10 Hz).
        keep_truth: keep each sensor's latest ground truth in :attr:`lidar_truth` (per-point labels)
            and :attr:`camera_truth` (object id per box, -1 false positive) for quality benchmarks.
    """

    def __init__(
        self,
        world: World,
        seed: int,
        tick_us: int,
        lidar_specs: tuple[LidarSpec, ...] | None = None,
        cameras: tuple[PinholeCamera, ...] | None = None,
        daylight: float = 1.0,
        weather_intensity: float = 1.0,
        snow_cover_lane_m: float = 0.0,
        camera_period_ticks: int = 10,
        camera_config: CameraDetectorConfig | None = None,
        keep_truth: bool = False,
    ) -> None:
        if tick_us <= 0 or camera_period_ticks <= 0:
            raise ConfigError(
                "RawSensorRig: expected tick_us > 0 and camera_period_ticks > 0, "
                f"got {tick_us}, {camera_period_ticks}"
            )
        self.world = world
        self.tick_us = tick_us
        self.lidar_specs = lidar_specs or default_lidar_rig(world.geometry)
        for spec in self.lidar_specs:
            if spec.period_us % tick_us:
                raise ConfigError(
                    f"RawSensorRig: LiDAR {spec.sensor_id!r} period {spec.period_us} us is not a multiple of "
                    f"the tick {tick_us} us"
                )
        self.lidar = LidarSimulator(
            static_scene(world.hdmap),
            self.lidar_specs,
            lidar_weather(world.weather, weather_intensity, snow_cover_lane_m),
            seed,
            world.geometry,
        )
        self.cameras = tuple(
            CameraDetectorModel(cam, world.weather, daylight, seed, camera_config)
            for cam in (cameras or default_cameras(world.geometry))
        )
        self.camera_period_ticks = camera_period_ticks
        self.keep_truth = keep_truth
        self.lidar_truth: dict[str, LidarTruth] = {}
        self.camera_truth: dict[str, np.ndarray] = {}
        longest = max(s.period_us for s in self.lidar_specs)
        self._history: deque[tuple[int, float, float, float]] = deque(maxlen=longest // tick_us + 2)

    def sample(self, tick: int) -> list[tuple[SensorFrame, int]]:
        """Frames captured by ``tick``: (frame, latency from its stamp to delivery in us)."""
        now = tick * self.tick_us
        s = self.world.ego.state
        self._history.append((now, s.x_m, s.y_m, s.yaw_rad))
        out: list[tuple[SensorFrame, int]] = []
        objects: DynamicObjects | None = None
        tracks: dict[int, EgoTrack] = {}  # by sweep start: units of one period share their track
        for spec in self.lidar_specs:
            # A sweep ends now and started one period ago; the first one needs a full period of poses.
            if tick % (spec.period_us // self.tick_us) or now < spec.period_us:
                continue
            if objects is None:
                objects = DynamicObjects.from_agents(self.world.agents)
            start = now - spec.period_us
            track = tracks.get(start)
            if track is None:
                hist = np.array([h for h in self._history if h[0] >= start - self.tick_us], dtype=np.float64)
                track = tracks[start] = EgoTrack(
                    t_us=hist[:, 0].astype(np.int64), x_m=hist[:, 1], y_m=hist[:, 2], yaw_rad=hist[:, 3]
                )
            if self.keep_truth:
                sweep, truth = self.lidar.sweep_with_truth(spec.sensor_id, Stamp(start), track, objects, now)
                self.lidar_truth[spec.sensor_id] = truth
            else:
                sweep = self.lidar.sweep(spec.sensor_id, Stamp(start), track, objects, now)
            out.append((sweep, spec.period_us + spec.latency_us))
        if tick % self.camera_period_ticks == 0:
            scene = CameraScene.from_agents(SE2(s.x_m, s.y_m, s.yaw_rad), self.world.agents)
            for cam in self.cameras:
                dets, ids = cam.detect_with_truth(scene, Stamp(now))
                if self.keep_truth:
                    self.camera_truth[cam.camera_id] = ids
                out.append((dets, cam.config.latency_us))
        return out
