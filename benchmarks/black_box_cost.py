"""Black-box cost: per-tick recording into the rolling window vs writing every message with the mcap writer.

Run: python benchmarks/black_box_cost.py [--seconds 40] [--lidar-points 5000] [--repeats 3] [--json out.json]

A synthetic stack stream at the loop's 100 Hz (IMU 50 Hz, radar 20 Hz, GNSS, LiDAR, pose, tracks, path,
decision and status at 10 Hz, the detections the tracker consumed as the stack outputs them: two radar
lists of 8 objects per planning cycle; a command every tick) is built first, so only recording is timed.
Compared,
per tick of the loop (median and p95 over ticks, then the median over repeats):

- black box: ``BlackBox.record_frames`` + ``record_output`` + ``record`` (references into a deque);
- baseline: what a user would otherwise do, write each message into an open ``mcap.writer.Writer``
  synchronously in the loop (same JSON encoding);
- the trigger call on the loop (window snapshot), the dump's duration on the background thread, and the
  per-tick recording cost while that dump runs (the thread shares the GIL with the loop).

One core (affinity pinned, BLAS one thread), so the background thread competes with the loop as it would
on a busy vehicle computer.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from mcap.writer import CompressionType, Writer
from rich.console import Console
from rich.table import Table

from lastmile.core.geometry import SE2
from lastmile.core.objects import DETECTION_COLUMNS, TRACK_COLUMNS, DetectedObjects, TrackedObjects
from lastmile.core.sensor_frames import GnssInsFrame, ImuFrame, LidarSweep, RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import (
    ActuatorCommand,
    BehaviourDecision,
    BehaviourState,
    LocalizationEstimate,
    StackOutput,
    Trajectory,
)
from lastmile.recorder import mcap_codec
from lastmile.recorder.black_box import BlackBox, BlackBoxConfig, sensor_topic
from lastmile.recorder.topic_recorder import DETECTIONS_TOPIC

TICK_US = 10_000

Tick = tuple[int, list[Any], StackOutput, list[tuple[str, Any]]]


def build_stream(seconds: float, lidar_points: int, seed: int) -> list[Tick]:
    rng = np.random.default_rng(seed)
    ticks: list[Tick] = []
    for tick in range(round(seconds * 1e6 / TICK_US)):
        now = tick * TICK_US
        x = 3.0 * now / 1e6
        frames: list[Any] = []
        extra: list[tuple[str, Any]] = []
        if tick % 2 == 0:
            frames.append(
                ImuFrame(
                    stamp=Stamp(now), yaw_rate_radps=float(rng.normal()), accel_x_mps2=0.0, accel_y_mps2=0.0
                )
            )
        if tick % 5 == 0:
            frames.append(
                RadarFrame(stamp=Stamp(now), sensor_id="radar_front", objects=rng.normal(size=(8, 6)))
            )
        decision = None
        detections = None
        if tick % 10 == 0:
            frames.append(
                GnssInsFrame(
                    stamp=Stamp(now),
                    x_m=x,
                    y_m=0.0,
                    yaw_rad=0.0,
                    speed_mps=3.0,
                    pos_std_m=0.02,
                    yaw_std_rad=0.004,
                )
            )
            pts = rng.normal(size=(lidar_points, 6)).astype(np.float32)
            frames.append(LidarSweep(stamp=Stamp(now), sensor_id="lidar_top", points=pts))
            extra.append(
                (
                    "/localization/estimate",
                    LocalizationEstimate(
                        stamp=Stamp(now),
                        map_from_base=SE2(x, 0.0, 0.0),
                        speed_mps=3.0,
                        yaw_rate_radps=0.0,
                        pos_std_m=0.05,
                        yaw_std_rad=0.01,
                        valid=True,
                    ),
                )
            )
            table = rng.normal(size=(10, len(TRACK_COLUMNS)))
            extra.append(
                ("/tracking/tracks", TrackedObjects(stamp=Stamp(now), ids=np.arange(10), table=table))
            )
            path = np.c_[np.linspace(x, x + 30, 61), np.zeros((61, 3)), np.linspace(0, 30, 61)]
            extra.append(("/planning/trajectory", Trajectory(stamp=Stamp(now), points=path, route_s0_m=x)))
            decision = BehaviourDecision(
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
            det_table = rng.normal(size=(8, len(DETECTION_COLUMNS)))
            det_table[:, DETECTION_COLUMNS.index("class_id")] = 0.0
            detections = tuple(
                DetectedObjects(
                    stamp=Stamp(now - k * 50_000), frame="map", source="radar_front", table=det_table
                )
                for k in (1, 0)
            )
        out = StackOutput(
            command=ActuatorCommand(
                stamp=Stamp(now), accel_mps2=0.1, steer_front_rad=0.0, steer_rear_rad=0.0
            ),
            decision=decision,
            detections=detections,
        )
        ticks.append((now, frames, out, extra))
    return ticks


def _percentiles_us(samples_ns: list[int]) -> tuple[float, float]:
    arr = np.asarray(samples_ns, dtype=float) / 1e3
    return float(np.percentile(arr, 50)), float(np.percentile(arr, 95))


def _max_us(samples_ns: list[int]) -> float:
    return max(samples_ns) / 1e3


def _p99_us(samples_ns: list[int]) -> float:
    return float(np.percentile(np.asarray(samples_ns, dtype=float), 99)) / 1e3


def run_black_box(ticks: list[Tick], out_dir: Path) -> dict[str, float]:
    bb = BlackBox(BlackBoxConfig(out_dir=out_dir))
    per_tick: list[int] = []
    clock = time.perf_counter_ns
    half = len(ticks) * 3 // 4
    for now, frames, out, extra in ticks[:half]:
        t0 = clock()
        bb.record_frames(now, frames)
        bb.record_output(now, out)
        for topic, msg in extra:
            bb.record(now, topic, msg)
        per_tick.append(clock() - t0)
    t0 = clock()
    future = bb.trigger("takeover", ticks[half - 1][0], "benchmark")
    trigger_ns = clock() - t0
    dump_start = time.perf_counter()
    during: list[int] = []
    # Keep the loop recording (no sleeping: the worst case for GIL sharing) until the dump is written,
    # cycling through the rest of the stream with advancing times.
    rest = ticks[half:]
    shift = 0
    while not future.done():
        for now, frames, out, extra in rest:
            t = now + shift
            t0 = clock()
            bb.record_frames(t, frames)
            bb.record_output(t, out)
            for topic, msg in extra:
                bb.record(t, topic, msg)
            during.append(clock() - t0)
            if future.done():
                break
        shift += len(rest) * TICK_US
    path = future.result()
    dump_s = time.perf_counter() - dump_start
    bb.close()
    p50, p95 = _percentiles_us(per_tick)
    d50, d95 = _percentiles_us(during) if during else (float("nan"), float("nan"))
    return {
        "record_p50_us": p50,
        "record_p95_us": p95,
        "record_p99_us": _p99_us(per_tick),
        "record_max_us": _max_us(per_tick),
        "trigger_call_us": trigger_ns / 1e3,
        "dump_s": dump_s,
        "record_during_dump_p50_us": d50,
        "record_during_dump_p95_us": d95,
        "record_during_dump_p99_us": _p99_us(during) if during else float("nan"),
        "record_during_dump_max_us": _max_us(during) if during else float("nan"),
        "ticks_during_dump": len(during),
        "dump_mbytes": path.stat().st_size / 1e6,
    }


def run_sync_mcap(ticks: list[Tick], out_dir: Path) -> dict[str, float]:
    """Baseline: every message written synchronously with the mcap writer from the loop."""
    per_tick: list[int] = []
    clock = time.perf_counter_ns
    with open(out_dir / "sync.mcap", "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="benchmark")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}

        def write(now: int, topic: str, msg: Any) -> None:
            spec, data = mcap_codec.lossless_record(msg)
            if topic not in channels:
                if spec.schema not in schemas:
                    schemas[spec.schema] = w.register_schema(
                        name=spec.schema, encoding=spec.schema_encoding, data=spec.schema_data
                    )
                channels[topic] = w.register_channel(
                    topic=topic, message_encoding=spec.message_encoding, schema_id=schemas[spec.schema]
                )
            w.add_message(channels[topic], log_time=now * 1000, data=data, publish_time=now * 1000)

        for now, frames, out, extra in ticks:
            t0 = clock()
            for f in frames:
                write(now, sensor_topic(f), f)
            if out.command is not None:
                write(now, "/stack/command", out.command)
            if out.decision is not None:
                write(now, "/decision/behaviour", out.decision)
            for det in out.detections or ():
                write(now, DETECTIONS_TOPIC, det)
            for topic, msg in extra:
                write(now, topic, msg)
            per_tick.append(clock() - t0)
        w.finish()
    p50, p95 = _percentiles_us(per_tick)
    return {
        "record_p50_us": p50,
        "record_p95_us": p95,
        "record_p99_us": _p99_us(per_tick),
        "record_max_us": _max_us(per_tick),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=40.0, help="loop time to record (s)")
    parser.add_argument("--lidar-points", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-pin", action="store_true", help="do not pin the process to one core")
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/black_box_cost.json"))
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity") and not args.no_pin:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    ticks = build_stream(args.seconds, args.lidar_points, seed=0)
    bb_runs, sync_runs = [], []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            bb_runs.append(run_black_box(ticks, Path(tmp)))
            sync_runs.append(run_sync_mcap(ticks, Path(tmp)))

    def med(runs: list[dict[str, float]], key: str) -> float:
        return statistics.median(r[key] for r in runs)

    bb = {k: med(bb_runs, k) for k in bb_runs[0]}
    sync = {k: med(sync_runs, k) for k in sync_runs[0]}
    ratio_p50 = sync["record_p50_us"] / bb["record_p50_us"]
    ratio_p95 = sync["record_p95_us"] / bb["record_p95_us"]
    table = Table(
        title=f"black box cost per 10 ms tick, {args.seconds:g} s, LiDAR {args.lidar_points} pts, one core"
    )
    for col in ("what", "median", "p95", "p99", "max"):
        table.add_column(col, justify="right" if col != "what" else "left")

    def row(name: str, d: dict[str, float], prefix: str) -> None:
        table.add_row(name, *(f"{d[f'{prefix}_{q}_us']:.1f}" for q in ("p50", "p95", "p99", "max")))

    row("black box record (µs/tick)", bb, "record")
    row("sync mcap writer (µs/tick)", sync, "record")
    ratio_p99 = sync["record_p99_us"] / bb["record_p99_us"]
    ratio_max = sync["record_max_us"] / bb["record_max_us"]
    table.add_row(
        "ratio sync / black box",
        f"{ratio_p50:.0f}x",
        f"{ratio_p95:.0f}x",
        f"{ratio_p99:.0f}x",
        f"{ratio_max:.0f}x",
    )
    row("black box record while dumping (µs/tick)", bb, "record_during_dump")
    table.add_row("trigger call on the loop (µs)", f"{bb['trigger_call_us']:.0f}", "", "")
    table.add_row(
        "dump on the background thread (s)", f"{bb['dump_s']:.2f}", "", "", f"{bb['dump_mbytes']:.1f} MB"
    )
    Console().print(table)
    result = {
        "seconds": args.seconds,
        "lidar_points": args.lidar_points,
        "repeats": args.repeats,
        "black_box": bb,
        "sync_mcap": sync,
        "ratio_sync_over_black_box_p50": ratio_p50,
        "ratio_sync_over_black_box_p95": ratio_p95,
        "ratio_sync_over_black_box_p99": ratio_p99,
        "ratio_sync_over_black_box_max": ratio_max,
        "pinned_to_one_core": not args.no_pin,
        "runs": {"black_box": bb_runs, "sync_mcap": sync_runs},
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
