"""A synthetic stack stream (what a loop would hand the black box each tick), seeded and repeatable."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from lastmile.core.geometry import SE2
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.safety_messages import FailSafeLevel, SafetyDirective
from lastmile.core.sensor_frames import GnssInsFrame, ImuFrame, LidarSweep, RadarFrame, SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import (
    ActuatorCommand,
    BehaviourDecision,
    BehaviourState,
    Heartbeat,
    LocalizationEstimate,
    StackOutput,
    Trajectory,
    VehicleStatus,
)
from lastmile.recorder.black_box import BlackBox

TICK_US = 10_000


def tick_messages(
    tick: int, rng: np.random.Generator, lidar_points: int = 500
) -> tuple[int, list[SensorFrame], StackOutput, list[tuple[str, object]]]:
    """Frames, stack output and extra (topic, message) pairs of one 10 ms tick."""
    now = tick * TICK_US
    x = 3.0 * now / 1e6
    frames: list[SensorFrame] = []
    extra: list[tuple[str, object]] = []
    if tick % 2 == 0:
        frames.append(
            ImuFrame(
                stamp=Stamp(now - 4_000),
                yaw_rate_radps=float(rng.normal(0, 0.003)),
                accel_x_mps2=0.0,
                accel_y_mps2=0.0,
            )
        )
    if tick % 5 == 0:
        frames.append(
            RadarFrame(stamp=Stamp(now - 45_000), sensor_id="front", objects=rng.normal(size=(2, 6)))
        )
    if tick % 10 == 0:
        frames.append(
            GnssInsFrame(
                stamp=Stamp(now - 30_000),
                x_m=x,
                y_m=0.0,
                yaw_rad=0.0,
                speed_mps=3.0,
                pos_std_m=0.02,
                yaw_std_rad=0.004,
            )
        )
        frames.append(
            LidarSweep(
                stamp=Stamp(now - 50_000),
                sensor_id="top",
                points=rng.normal(size=(lidar_points, 6)).astype(np.float32),
            )
        )
        est = LocalizationEstimate(
            stamp=Stamp(now),
            map_from_base=SE2(x, 0.0, 0.0),
            speed_mps=3.0,
            yaw_rate_radps=0.0,
            pos_std_m=0.05,
            yaw_std_rad=0.01,
            valid=True,
        )
        extra.append(("/localization/estimate", est))
        table = np.zeros((2, len(TRACK_COLUMNS)))
        table[:, 0] = x + np.array([10.0, 20.0])
        table[:, 4:6] = [4.0, 1.8]
        extra.append(
            ("/tracking/tracks", TrackedObjects(stamp=Stamp(now), ids=np.array([3, 9]), table=table))
        )
        pts = np.c_[
            np.linspace(x, x + 20, 21), np.zeros(21), np.zeros(21), np.zeros(21), np.linspace(0, 20, 21)
        ]
        extra.append(("/planning/trajectory", Trajectory(stamp=Stamp(now), points=pts, route_s0_m=x)))
        extra.append(("/safety/directive", SafetyDirective(stamp=Stamp(now), level=FailSafeLevel.NONE)))
    decision = (
        BehaviourDecision(
            stamp=Stamp(now),
            state=BehaviourState.NORMAL_DRIVING,
            speed_limit_mps=5.0,
            stop_at_s_m=None,
            pullover_spot=None,
            merge_from_s_m=None,
            door_open=False,
            risk_track_id=-1,
            reason="cruise",
        )
        if tick % 10 == 0
        else None
    )
    status = (
        VehicleStatus(
            stamp=Stamp(now),
            map_from_base=SE2(x, 0.0, 0.0),
            speed_mps=3.0,
            state=BehaviourState.NORMAL_DRIVING,
            route_s_m=float("nan"),
            door_open=False,
            healthy=True,
        )
        if tick % 10 == 0
        else None
    )
    out = StackOutput(
        command=ActuatorCommand(
            stamp=Stamp(now - now % 20_000), accel_mps2=0.1, steer_front_rad=0.01, steer_rear_rad=-0.01
        ),
        status=status,
        decision=decision,
        heartbeats=(Heartbeat(stamp=Stamp(now), module="planning", healthy=True),) if tick % 10 == 0 else (),
    )
    return now, frames, out, extra


def record_ticks(
    bb: BlackBox, first_tick: int, n_ticks: int, seed: int = 0, lidar_points: int = 500
) -> Iterator[int]:
    rng = np.random.default_rng(seed + first_tick)
    for tick in range(first_tick, first_tick + n_ticks):
        now, frames, out, extra = tick_messages(tick, rng, lidar_points)
        bb.record_frames(now, frames)
        bb.record_output(now, out)
        for topic, msg in extra:
            bb.record(now, topic, msg)
        yield now


def repo_root() -> Path:
    return Path(__file__).resolve().parents[2]
