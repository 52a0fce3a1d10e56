"""Read a black-box MCAP back into our messages: summary, frames for re-running the stack, PNG rendering."""

from __future__ import annotations

import json
import math
import struct
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader

from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.core.sensor_frames import LIDAR_COLUMNS, RADAR_COLUMNS, LidarSweep, RadarFrame, SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import (
    ActuatorCommand,
    BehaviourDecision,
    LocalizationEstimate,
    Trajectory,
)
from lastmile.recorder import mcap_codec
from lastmile.recorder.black_box import EVENT_SCHEMA, SUMMARY_METADATA
from lastmile.recorder.mcap_codec import RecordingError

_SENSOR_TYPES = (
    "GnssInsFrame",
    "ImuFrame",
    "WheelOdometryFrame",
    "RadarFrame",
    "DoorSensorFrame",
    "StopCallFrame",
    "LidarSweep",
    "CameraDetections",
    "TrafficLightDetections",
)


@dataclass(frozen=True, slots=True)
class RecordedMessage:
    """One lossless record: log time (when the loop saw it), topic and the rebuilt message."""

    log_time_us: int
    topic: str
    message: Any


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelSummary:
    topic: str
    schema: str
    count: int
    first_us: int
    last_us: int


@dataclass(frozen=True, kw_only=True)
class Recording:
    """A black-box file read back.

    Attributes:
        messages: lossless records in log-time order (Foxglove view channels are left out).
        channels: every channel in the file, views included.
        events: the trigger event records (trigger, time_us, reason, window bounds).
        metadata: every metadata record as (name, dict); ``operator_summary`` among them once added.
        attachments: (name, media type, bytes), e.g. the operator's audio summary.
    """

    path: Path
    messages: tuple[RecordedMessage, ...]
    channels: tuple[ChannelSummary, ...]
    events: tuple[dict[str, str], ...] = ()
    metadata: tuple[tuple[str, dict[str, str]], ...] = ()
    attachments: tuple[tuple[str, str, bytes], ...] = field(default_factory=tuple)

    @property
    def span_us(self) -> tuple[int, int]:
        if not self.messages:
            return (0, 0)
        return self.messages[0].log_time_us, self.messages[-1].log_time_us

    @property
    def operator_summary(self) -> str | None:
        for name, data in self.metadata:
            if name == SUMMARY_METADATA:
                return data.get("text", "")
        return None

    def on(self, topic: str) -> list[Any]:
        """Messages of one topic, in log-time order."""
        return [m.message for m in self.messages if m.topic == topic]

    def ticks(self, tick_us: int | None = None) -> Iterator[tuple[Stamp, tuple[SensorFrame, ...]]]:
        """(now, frames) in loop order: exactly the input ``stack.tick(now, frames)`` saw, for playback.

        Frames are grouped by the tick they were delivered at (their log time) and kept in delivery
        order, which need not be capture order, just as the loop handed them over.

        Args:
            tick_us: the loop's base tick. Given, every tick from the first recorded one to the last is
                yielded, with no frames where none arrived: a stack counts its ticks to schedule its
                modules, so playback must not skip any. None: only ticks that delivered frames.
        """
        grouped: dict[int, list[SensorFrame]] = {}
        for m in self.messages:
            if type(m.message).__name__ in _SENSOR_TYPES:
                grouped.setdefault(m.log_time_us, []).append(m.message)
        if tick_us is None:
            for now in sorted(grouped):
                yield Stamp(now), tuple(grouped[now])
            return
        if tick_us <= 0:
            raise RecordingError(f"ticks: expected a positive tick_us, got {tick_us}")
        first, last = self.span_us
        for now in range(first, last + 1, tick_us):
            yield Stamp(now), tuple(grouped.get(now, ()))

    def frames_in_capture_order(self) -> list[SensorFrame]:
        """Every sensor frame sorted by capture stamp (stable for equal stamps)."""
        frames = [m.message for m in self.messages if type(m.message).__name__ in _SENSOR_TYPES]
        return sorted(frames, key=lambda f: int(f.stamp))


def _load_stream(path: Path, stream: Any) -> Recording:
    reader = make_reader(stream)
    messages: list[RecordedMessage] = []
    counts: Counter[tuple[str, str]] = Counter()
    first: dict[tuple[str, str], int] = {}
    last: dict[tuple[str, str], int] = {}
    events: list[dict[str, str]] = []
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        schema_name = schema.name if schema is not None else ""
        key = (channel.topic, schema_name)
        t_us = message.log_time // 1000
        counts[key] += 1
        first.setdefault(key, t_us)
        last[key] = t_us
        if schema_name == EVENT_SCHEMA:
            events.append({k: str(v) for k, v in json.loads(message.data).items()})
        elif schema_name.startswith("lastmile.") or schema_name == mcap_codec.LIDAR_SCHEMA:
            messages.append(
                RecordedMessage(t_us, channel.topic, mcap_codec.decode_message(schema_name, message.data))
            )
    metadata = tuple((m.name, dict(m.metadata)) for m in reader.iter_metadata())
    attachments = tuple((a.name, a.media_type, bytes(a.data)) for a in reader.iter_attachments())
    channels = tuple(
        ChannelSummary(topic=t, schema=s, count=n, first_us=first[(t, s)], last_us=last[(t, s)])
        for (t, s), n in sorted(counts.items())
    )
    return Recording(
        path=path,
        messages=tuple(messages),
        channels=channels,
        events=tuple(events),
        metadata=metadata,
        attachments=attachments,
    )


def read_recording(path: str | Path) -> Recording:
    """Read a black-box MCAP file, or a spool directory of chunk files (merged in time order).

    Raises:
        RecordingError: the path is missing, not an MCAP file, truncated, or holds undecodable data.
    """
    p = Path(path)
    if p.is_dir():
        chunks = sorted(p.glob("chunk_*.mcap"))
        if not chunks:
            raise RecordingError(f"expected an MCAP file or a spool directory with chunk_*.mcap, got {p}")
        parts = [read_recording(c) for c in chunks]
        msgs = tuple(sorted((m for r in parts for m in r.messages), key=lambda m: m.log_time_us))
        chans = tuple(c for r in parts for c in r.channels)
        return Recording(path=p, messages=msgs, channels=_merge_channels(chans))
    if not p.is_file():
        raise RecordingError(f"expected an MCAP file, got {p} (no such file)")
    try:
        with open(p, "rb") as fh:
            return _load_stream(p, fh)
    except (McapError, ValueError, KeyError, EOFError, OSError, struct.error) as exc:
        # Truncated or foreign bytes surface from the mcap reader as any of these.
        raise RecordingError(f"expected a readable MCAP file, got {p}: {type(exc).__name__}: {exc}") from None


def _merge_channels(chans: tuple[ChannelSummary, ...]) -> tuple[ChannelSummary, ...]:
    merged: dict[tuple[str, str], ChannelSummary] = {}
    for c in chans:
        key = (c.topic, c.schema)
        old = merged.get(key)
        merged[key] = (
            c
            if old is None
            else ChannelSummary(
                topic=c.topic,
                schema=c.schema,
                count=old.count + c.count,
                first_us=min(old.first_us, c.first_us),
                last_us=max(old.last_us, c.last_us),
            )
        )
    return tuple(merged[k] for k in sorted(merged))


# --- rendering -----------------------------------------------------------------------------------------
def render_png_sequence(
    recording: Recording,
    out_dir: str | Path,
    *,
    fps: float = 10.0,
    view_m: float = 40.0,
    max_frames: int | None = None,
) -> list[Path]:
    """Top-down PNG frames (ego pose, trajectory, tracks, LiDAR/radar points) at ``fps`` of log time.

    Sensor points are drawn around the ego pose as if the sensor sat at the rear axle (the recording
    does not carry mounting poses): good for seeing what the stack saw, not for measuring.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0, t1 = recording.span_us
    step = round(1e6 / fps)
    latest: dict[str, Any] = {}
    msgs = recording.messages
    i = 0
    paths: list[Path] = []
    fig, ax = plt.subplots(figsize=(6.4, 6.4), dpi=100)
    try:
        for k, t in enumerate(range(t0, t1 + 1, step)):
            if max_frames is not None and k >= max_frames:
                break
            while i < len(msgs) and msgs[i].log_time_us <= t:
                m = msgs[i].message
                if isinstance(
                    m,
                    LocalizationEstimate | TrackedObjects | Trajectory | BehaviourDecision | ActuatorCommand,
                ):
                    latest[type(m).__name__] = m
                elif isinstance(m, LidarSweep | RadarFrame):
                    latest[f"pts:{msgs[i].topic}"] = m
                i += 1
            ax.clear()
            est = latest.get("LocalizationEstimate")
            cx, cy, yaw = (
                (est.map_from_base.x_m, est.map_from_base.y_m, est.map_from_base.yaw_rad)
                if est
                else (0.0, 0.0, 0.0)
            )
            c, s = math.cos(yaw), math.sin(yaw)
            for key, m in latest.items():
                if not key.startswith("pts:"):
                    continue
                if isinstance(m, LidarSweep):
                    px, py = m.points[:, LIDAR_COLUMNS.index("x_m")], m.points[:, LIDAR_COLUMNS.index("y_m")]
                    ax.scatter(cx + c * px - s * py, cy + s * px + c * py, s=0.5, c="0.4")
                else:
                    px, py = (
                        m.objects[:, RADAR_COLUMNS.index("x_m")],
                        m.objects[:, RADAR_COLUMNS.index("y_m")],
                    )
                    ax.scatter(cx + c * px - s * py, cy + s * px + c * py, s=10, marker="x", c="tab:purple")
            traj = latest.get("Trajectory")
            if traj is not None:
                ax.plot(traj.points[:, 0], traj.points[:, 1], "-", c="tab:green", lw=2)
            tracks = latest.get("TrackedObjects")
            if tracks is not None:
                col = {n: TRACK_COLUMNS.index(n) for n in ("x_m", "y_m", "yaw_rad", "length_m", "width_m")}
                for row in tracks.table:
                    ax.add_patch(
                        Polygon(
                            _box(
                                row[col["x_m"]],
                                row[col["y_m"]],
                                row[col["yaw_rad"]],
                                row[col["length_m"]],
                                row[col["width_m"]],
                            ),
                            closed=True,
                            fc="tab:orange",
                            alpha=0.6,
                        )
                    )
            if est is not None:
                ax.add_patch(
                    Polygon(
                        _box(cx + 1.45 * c, cy + 1.45 * s, yaw, 4.6, 2.0),
                        closed=True,
                        fc="tab:blue",
                        alpha=0.8,
                    )
                )
            decision = latest.get("BehaviourDecision")
            cmd = latest.get("ActuatorCommand")
            title = f"t = {t / 1e6:.2f} s"
            if est is not None:
                title += f"  v = {est.speed_mps:.1f} m/s"
            if decision is not None:
                title += f"  {decision.state.value}"
            if cmd is not None and cmd.emergency_brake:
                title += "  E-BRAKE"
            ax.set_title(title, fontsize=9)
            ax.set_xlim(cx - view_m / 2, cx + view_m / 2)
            ax.set_ylim(cy - view_m / 2, cy + view_m / 2)
            ax.set_aspect("equal")
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
            path = out / f"frame_{k:05d}.png"
            fig.savefig(path)
            paths.append(path)
    finally:
        plt.close(fig)
    return paths


def _box(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array(
        [
            [length / 2, width / 2],
            [-length / 2, width / 2],
            [-length / 2, -width / 2],
            [length / 2, -width / 2],
        ]
    )
    return np.c_[x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]]
