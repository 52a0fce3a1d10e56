"""Compiles the simulated LiDAR's kernels into the user's cache ahead of the first run (``lastmile warmup``).

The kernels are compiled for the argument types the simulator calls them with: a small sweep of a
16-beam unit over a road with a raised sidewalk, a wall, a pedestrian and a car, cast in clear air (every
compiled pass) and in rain (the atmosphere's loss), through :class:`LidarSimulator` itself. Afterwards
every kernel must hold a compiled signature, else :func:`warm_up` says which did not.

``python -m lastmile.sim.lidar_warmup`` runs it alone.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from lastmile.core.kernel_warmup import WarmupReport, print_report, warmup_report
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim import lidar_kernel
from lastmile.sim.agents import Agent
from lastmile.sim.lidar import LidarSimulator
from lastmile.sim.lidar_ground import RESOLUTION_M, GroundRaster
from lastmile.sim.lidar_rig import BLIND_SPOT_ELEVATIONS_DEG, EgoTrack, LidarSpec
from lastmile.sim.lidar_scene import DynamicObjects, PointLabel, Segments, StaticLidarScene
from lastmile.sim.lidar_weather import lidar_weather
from lastmile.sim.weather import Weather


def entry_kernels() -> dict[str, object]:
    """The kernel functions Python calls (the private ``_helpers`` are compiled into their callers)."""
    out: dict[str, object] = {}
    for name, value in vars(lidar_kernel).items():
        own = getattr(getattr(value, "py_func", None), "__module__", None) == lidar_kernel.__name__
        if own and hasattr(value, "signatures") and not name.startswith("_"):
            out[f"lidar_kernel.{name}"] = value
    return out


class _Road:
    """A 40 x 20 m ground raster: road for |y| < 3.5 m, raised sidewalk beyond (a stand-in for
    :class:`GroundRaster`, which is built from a map)."""

    def __init__(self) -> None:
        self.x0_m, self.y0_m = -20.0, -10.0
        self.width, self.height = round(40.0 / RESOLUTION_M), round(20.0 / RESOLUTION_M)
        y = self.y0_m + (np.arange(self.height) + 0.5) * RESOLUTION_M
        self.road = np.broadcast_to((np.abs(y) < 3.5)[:, None], (self.height, self.width)).copy()


def _scene() -> StaticLidarScene:
    wall = Segments(
        p0=np.array([[-10.0, 6.0]]),
        p1=np.array([[10.0, 6.0]]),
        z_min_m=np.zeros(1),
        z_max_m=np.full(1, 3.0),
        label=np.full(1, PointLabel.BUILDING, dtype=np.int8),
        reflectivity=np.full(1, 0.3),
        retro=np.zeros(1, dtype=bool),
    )
    ground: GroundRaster = _Road()  # type: ignore[assignment]  # the raster's attributes, no map
    return StaticLidarScene(
        segments=wall, cylinders=DynamicObjects.empty().cylinders, ground=ground, curb_height_m=0.15
    )


def warm_up() -> WarmupReport:
    """Cast a small sweep in clear air and in rain so that each kernel is compiled (or loaded)."""
    t0 = time.perf_counter()
    spec = LidarSpec(
        sensor_id="warmup",
        x_m=0.0,
        y_m=0.0,
        z_m=1.0,
        yaw_rad=0.0,
        elevations_deg=BLIND_SPOT_ELEVATIONS_DEG,
        azimuth_res_deg=2.0,
        max_range_m=30.0,
    )
    road_users = [
        Agent(id=1, cls=ObjectClass.CAR, x_m=8.0, y_m=1.5, yaw_rad=0.0, speed_mps=2.0, length_m=4.5,
              width_m=1.8, rcs_dbsm=10.0),
        Agent(id=2, cls=ObjectClass.PEDESTRIAN, x_m=4.0, y_m=-4.5, yaw_rad=1.5, speed_mps=1.0,
              length_m=0.5, width_m=0.5, rcs_dbsm=-5.0),
    ]  # fmt: skip
    objects = DynamicObjects.from_agents(road_users)
    ego = EgoTrack.constant(0, -5.0, 0.0, 0.0, speed_mps=3.0)
    for weather in (Weather.CLEAR, Weather.RAIN):
        sim = LidarSimulator(_scene(), (spec,), lidar_weather(weather), 0, VehicleGeometry())
        sim.sweep(spec.sensor_id, Stamp(0), ego, objects, 100_000)
    kernels = entry_kernels()
    return warmup_report(kernels, t0)


def main() -> int:
    return print_report("simulator", warm_up())


if __name__ == "__main__":
    sys.exit(main())
