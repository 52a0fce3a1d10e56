"""A mapping drive's recording: the LiDAR sweeps and the vehicle's own pose estimates of a whole run.

The black box keeps a rolling window and writes it on incidents; a mapping drive needs the whole run,
so this loop callback keeps what ``lastmile map build`` reads and nothing else: the LiDAR rig frames
(every sweep of a revolution, all units) once per ``min_travel_m`` of the estimated travel, the stack's
localization estimates (10 Hz) and the sensor mounts, written as one MCAP file at the end of the run
with the same channels and ``/tf`` as a black-box file. The travel is measured on the stack's own
estimate, never the simulator's truth.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.sensor_frames import LidarSweep
from lastmile.recorder.foxglove_views import ViewBuilder
from lastmile.recorder.mcap_dump import write_mcap
from lastmile.recorder.topic_recorder import sensor_topic
from lastmile.runner.loop import ClosedLoop, LoopCallback, TickRecord
from lastmile.runner.loop_callbacks import sensor_frame_mounts
from lastmile.stack.stack_settings import StackSettings

ESTIMATE_TOPIC = "/localization/estimate"


class LidarMapRecording(LoopCallback):
    """Keeps a run's LiDAR rig frames (thinned by travel) and pose estimates; writes them to ``path``."""

    def __init__(self, path: Path, min_travel_m: float = 1.0, stack: StackSettings | None = None) -> None:
        self.path = path
        self.stack = stack  # whose ``lidar_mounts`` file, if any, gives the mounts the drive records
        self.min_travel_m = min_travel_m
        self.entries: list[tuple[int, str, Any]] = []
        self.rig_frames = 0
        self._mounts: dict[str, np.ndarray] = {}
        self._last_xy: tuple[float, float] | None = None
        self._keep_stamp: int | None = None
        self._xy: tuple[float, float] | None = None

    def on_start(self, loop: ClosedLoop[Any]) -> None:
        from lastmile.runner.closed_loop import sensor_calibration  # closed_loop builds the loop itself

        self._mounts = {
            k: v
            for k, v in sensor_frame_mounts(sensor_calibration(loop.world, self.stack)).items()
            if k.startswith("lidar_")
        }

    def on_tick(self, record: TickRecord) -> None:
        now = int(record.now)
        out = record.output
        est = out.diagnostics.estimate if out is not None and out.diagnostics is not None else None
        if est is not None:
            self.entries.append((now, ESTIMATE_TOPIC, est))
            if est.valid:
                self._xy = (est.map_from_base.x_m, est.map_from_base.y_m)
        for frame in record.frames:
            if isinstance(frame, LidarSweep) and self._keep(int(frame.stamp)):
                self.entries.append((now, sensor_topic(frame), frame))

    def _keep(self, stamp_us: int) -> bool:
        """One decision per rig frame (its sweeps share the stamp): kept after enough travel."""
        if stamp_us == self._keep_stamp:
            return True
        xy = self._xy
        if xy is None:
            return False
        if self._last_xy is not None and math.dist(xy, self._last_xy) < self.min_travel_m:
            return False
        self._last_xy, self._keep_stamp = xy, stamp_us
        self.rig_frames += 1
        return True

    def on_end(self, loop: ClosedLoop[Any], ticks_run: int) -> None:
        self.entries.sort(key=lambda e: e[0])
        write_mcap(self.path, self.entries, views=ViewBuilder(sensor_mounts=self._mounts))
