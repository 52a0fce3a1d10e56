"""The black box: a rolling window of what the stack received, decided and commanded -> MCAP on a trigger.

WATonoBus keeps the last 30 s and, when the operator takes over, stores them with room for the operator's
spoken summary. Here any trigger (takeover, emergency stop, collision, crash) does the same. Recording is
a deque append of references to immutable messages; a trigger copies the deque (references only) and a
single background thread encodes and writes the file, so the control loop never waits for the disk.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from lastmile.core import frame_kinds
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.sensor_frames import (
    SensorFrame,
)
from lastmile.core.vehicle_messages import StackOutput
from lastmile.recorder import foxglove_schemas as fx
from lastmile.recorder import mcap_codec

TRIGGERS = ("takeover", "emergency_stop", "collision", "crash", "watchdog", "sigterm", "manual")
"""Trigger kinds; ``crash`` and ``sigterm`` are written synchronously (the process is going away)."""

EVENT_TOPIC = "/events"
EVENT_SCHEMA = "lastmile.BlackBoxEvent"
EVENT_METADATA = "black_box_event"
SUMMARY_METADATA = "operator_summary"
PROFILE = "lastmile.black_box"

_YIELD_EVERY_S = 0.001

Entry = tuple[int, str, Any]
"""(log time in microseconds, topic, message): what the window holds."""


@dataclass(frozen=True, slots=True, kw_only=True)
class BlackBoxConfig:
    """Attributes:
    out_dir: where dumps go (created on demand); files are ``blackbox_<trigger>_<t>s_<n>.mcap``.
    window_us: the rolling window: entries with log time in (newest - window, newest] are kept.
    cooldown_us: a trigger of the same kind within this time of the previous one is merged into it
        (a collision reported on consecutive ticks makes one file).
    spool_chunk_us: if set, the window is also written continuously as finalized MCAP chunks of this
        length under ``out_dir/spool``, so even SIGKILL leaves all but the last chunk readable.
    compression: MCAP chunk compression ("zstd", "lz4" or "none").
    sensor_mounts: base_from_sensor pose per sensor id, written as ``/tf_static`` transforms
        (base_link -> sensor id) so Foxglove can place point clouds, which are in their sensor's frame.
    """

    out_dir: Path
    window_us: int = 30_000_000
    cooldown_us: int = 5_000_000
    spool_chunk_us: int | None = None
    compression: str = "zstd"
    sensor_mounts: Mapping[str, SE2] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.window_us <= 0:
            raise ConfigError(f"BlackBoxConfig.window_us: expected > 0, got {self.window_us}")
        if self.spool_chunk_us is not None and not 0 < self.spool_chunk_us <= self.window_us:
            raise ConfigError(
                f"BlackBoxConfig.spool_chunk_us: expected in (0, window_us], got {self.spool_chunk_us}"
            )
        if self.compression not in ("zstd", "lz4", "none"):
            raise ConfigError(
                f"BlackBoxConfig.compression: expected zstd, lz4 or none, got {self.compression!r}"
            )


def sensor_topic(frame: SensorFrame) -> str:
    """The topic a sensor frame is recorded on."""
    return frame_kinds.frame_topic(frame)


def _compression(name: str) -> CompressionType:
    return {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[name]


def write_mcap(
    path: Path,
    entries: Sequence[Entry],
    *,
    events: Sequence[dict[str, Any]] = (),
    metadata: dict[str, dict[str, str]] | None = None,
    compression: str = "zstd",
    yield_gil: bool = False,
    sensor_mounts: Mapping[str, SE2] | None = None,
) -> Path:
    """Write entries (and event records) to ``path`` atomically: a temporary name, then a rename.

    With ``yield_gil`` (background writes) the thread gives up the GIL after every millisecond of
    work, so a busy loop waits about that long instead of the interpreter's 5 ms switch interval.

    Returns:
        ``path``; a reader never sees a half-written file under that name.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    schemas: dict[str, int] = {}
    channels: dict[tuple[str, str], int] = {}
    with open(tmp, "wb") as fh:
        w = Writer(fh, compression=_compression(compression))
        w.start(profile=PROFILE, library="lastmile")

        def channel(topic: str, schema: str, schema_bytes: bytes | None = None) -> int:
            key = (topic, schema)
            if key not in channels:
                if schema not in schemas:
                    data = schema_bytes if schema_bytes is not None else fx.SCHEMA_BYTES[schema]
                    schemas[schema] = w.register_schema(name=schema, encoding="jsonschema", data=data)
                channels[key] = w.register_channel(
                    topic=topic, message_encoding="json", schema_id=schemas[schema]
                )
            return channels[key]

        seq = 0
        last_yield = time.perf_counter()
        if sensor_mounts and entries:
            t0_us = entries[0][0]
            for sensor_id, mount in sorted(sensor_mounts.items()):
                pose = fx.planar_pose(mount.x_m, mount.y_m, mount.yaw_rad)
                tf = {
                    "timestamp": fx.time_of(t0_us),
                    "parent_frame_id": fx.BASE_FRAME,
                    "child_frame_id": sensor_id,
                    "translation": pose["position"],
                    "rotation": pose["orientation"],
                }
                w.add_message(
                    channel("/tf_static", "foxglove.FrameTransform"),
                    log_time=t0_us * 1000,
                    data=json.dumps(tf).encode(),
                    publish_time=t0_us * 1000,
                    sequence=seq,
                )
                seq += 1
        for log_us, topic, msg in entries:
            log_ns = log_us * 1000
            name, schema_bytes = mcap_codec.schema_of(msg)
            # MCAP times are unsigned; a frame captured before the loop's zero gets publish time 0.
            stamp_ns = max(int(getattr(msg, "stamp", log_us)), 0) * 1000
            w.add_message(
                channel(topic, name, schema_bytes),
                log_time=log_ns,
                data=mcap_codec.lossless_payload(msg),
                publish_time=stamp_ns,
                sequence=seq,
            )
            seq += 1
            if yield_gil and time.perf_counter() - last_yield > _YIELD_EVERY_S:
                time.sleep(0)
                last_yield = time.perf_counter()
            for view_topic, view_schema, payload in mcap_codec.foxglove_views(topic, msg):
                w.add_message(
                    channel(view_topic, view_schema),
                    log_time=log_ns,
                    data=payload,
                    publish_time=stamp_ns,
                    sequence=seq,
                )
                seq += 1
        for ev in events:
            t_ns = int(ev["time_us"]) * 1000
            w.add_message(
                channel(
                    EVENT_TOPIC, EVENT_SCHEMA, json.dumps({"title": EVENT_SCHEMA, "type": "object"}).encode()
                ),
                log_time=t_ns,
                data=json.dumps(ev).encode(),
                publish_time=t_ns,
                sequence=seq,
            )
            seq += 1
            log = {
                "timestamp": fx.time_of(int(ev["time_us"])),
                "level": 4 if ev["trigger"] in ("crash", "collision", "emergency_stop") else 3,
                "message": f"black box trigger {ev['trigger']}: {ev['reason']}",
                "name": "black_box",
                "file": "",
                "line": 0,
            }
            w.add_message(
                channel("/log", "foxglove.Log"),
                log_time=t_ns,
                data=json.dumps(log).encode(),
                publish_time=t_ns,
                sequence=seq,
            )
            seq += 1
            w.add_metadata(EVENT_METADATA, {k: str(v) for k, v in ev.items()})
        for name, data in (metadata or {}).items():
            w.add_metadata(name, data)
        w.finish()
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path


class BlackBox:
    """Rolling window of the stack's inputs, decisions and outputs; dumps it to MCAP on triggers.

    Wiring (one call per tick from the loop, after the stack and the safety gate; see README.md):
    ``record_frames(now, frames)``, ``record_output(now, output)`` and ``record(now, topic, msg)`` for
    anything else (tracks, trajectory, health, safety directive, gated command). Call
    ``trigger(kind, now, reason)`` on a takeover / e-stop / collision and ``dump("crash", ...)`` from the
    runner's exception handler.
    """

    def __init__(self, config: BlackBoxConfig) -> None:
        self.config = config
        self._window: deque[Entry] = deque()
        self._newest_us = 0
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="black-box")
        # Start the writer thread now: spawning it inside the first trigger would cost the loop ~ms.
        self._executor.submit(lambda: None).result()
        self._pending: list[Future[Path]] = []
        self._last_trigger: dict[str, tuple[int, Future[Path]]] = {}
        self._count = 0
        self._lock = threading.Lock()  # only around the counter and pending list (both threads touch them)
        self._spool_entries: list[Entry] = []
        self._spool_start_us: int | None = None
        self.dumps: list[Path] = []
        """Files written so far (dumps, not spool chunks), in completion order."""

    # --- recording (every tick, must be cheap) ------------------------------------------------------
    def record(self, now_us: int, topic: str, message: Any) -> None:
        """Keep a reference to ``message`` (an immutable core message) under ``topic`` at ``now_us``."""
        entry = (now_us, topic, message)
        window = self._window
        if now_us > self._newest_us:
            # Trim before appending: a SIGTERM handler that dumps while this call is interrupted then
            # sees the window of the previous tick, never the new entry beside the oldest expired one.
            self._newest_us = now_us
            horizon = now_us - self.config.window_us
            while window and window[0][0] <= horizon:
                window.popleft()
        window.append(entry)
        if self.config.spool_chunk_us is not None:
            self._spool(entry)

    def record_frames(self, now_us: int, frames: Iterable[SensorFrame]) -> None:
        """The sensor frames delivered to the stack at ``now_us``."""
        for frame in frames:
            self.record(now_us, sensor_topic(frame), frame)

    def record_output(self, now_us: int, output: StackOutput) -> None:
        """What one stack tick returned: command, status, decision (when new), HMI, heartbeats."""
        if output.command is not None:
            self.record(now_us, "/stack/command", output.command)
        if output.status is not None:
            self.record(now_us, "/stack/status", output.status)
        if output.decision is not None:
            self.record(now_us, "/decision/behaviour", output.decision)
        for hmi in output.hmi:
            self.record(now_us, "/stack/hmi", hmi)
        for beat in output.heartbeats:
            self.record(now_us, "/safety/heartbeat", beat)

    def window(self) -> tuple[Entry, ...]:
        """A snapshot of the window (references only)."""
        return tuple(self._window)

    # --- dumping ----------------------------------------------------------------------------------------
    def _path(self, kind: str, now_us: int) -> Path:
        with self._lock:
            self._count += 1
            n = self._count
        return self.config.out_dir / f"blackbox_{kind}_{now_us / 1e6:09.2f}s_{n:03d}.mcap"

    def _event(self, kind: str, now_us: int, reason: str, extra: dict[str, Any] | None) -> dict[str, Any]:
        if kind not in TRIGGERS:
            raise ConfigError(f"BlackBox trigger: expected one of {TRIGGERS}, got {kind!r}")
        ev: dict[str, Any] = {"trigger": kind, "time_us": int(now_us), "reason": reason}
        if self._window:
            ev["window_start_us"] = self._window[0][0]
            ev["window_end_us"] = self._window[-1][0]
        if extra:
            ev["extra"] = json.dumps(extra, default=str)
        return ev

    def trigger(
        self, kind: str, now_us: int, reason: str, extra: dict[str, Any] | None = None
    ) -> Future[Path]:
        """Write the window to a new MCAP file on the background thread; returns at once.

        A trigger of the same kind within ``cooldown_us`` of the previous returns that one's future.
        """
        last = self._last_trigger.get(kind)
        if last is not None and now_us - last[0] < self.config.cooldown_us:
            return last[1]
        ev = self._event(kind, now_us, reason, extra)
        snapshot = tuple(self._window)
        path = self._path(kind, now_us)
        future = self._executor.submit(self._write, path, snapshot, ev)
        self._last_trigger[kind] = (now_us, future)
        with self._lock:
            self._pending.append(future)
        return future

    def dump(self, kind: str = "crash", reason: str = "", now_us: int | None = None) -> Path:
        """Write the window now, in the calling thread (for a crash or SIGTERM: no thread to rely on)."""
        t = self._newest_us if now_us is None else now_us
        ev = self._event(kind, t, reason, None)
        return self._write(self._path(kind, t), tuple(self._window), ev, background=False)

    def _write(
        self, path: Path, entries: Sequence[Entry], event: dict[str, Any], background: bool = True
    ) -> Path:
        c = self.config
        out = write_mcap(
            path,
            entries,
            events=[event],
            compression=c.compression,
            yield_gil=background,
            sensor_mounts=c.sensor_mounts,
        )
        with self._lock:
            self.dumps.append(out)
        return out

    def flush(self, timeout_s: float | None = None) -> list[Path]:
        """Wait for the background writes started so far; returns their files."""
        with self._lock:
            pending, self._pending = self._pending, []
        return [f.result(timeout=timeout_s) for f in pending]

    def close(self) -> None:
        """Finish pending writes and the current spool chunk, stop the thread."""
        if self._spool_entries:
            self._flush_spool()
        self.flush()
        self._executor.shutdown(wait=True)

    # --- continuous spool (SIGKILL survivability) ----------------------------------------------------
    @property
    def spool_dir(self) -> Path:
        return self.config.out_dir / "spool"

    def _spool(self, entry: Entry) -> None:
        chunk = self.config.spool_chunk_us
        assert chunk is not None
        if self._spool_start_us is None:
            self._spool_start_us = entry[0]
        elif entry[0] - self._spool_start_us >= chunk:
            self._flush_spool()
            self._spool_start_us = entry[0]
        self._spool_entries.append(entry)

    def _flush_spool(self) -> None:
        entries, self._spool_entries = self._spool_entries, []
        if not entries:
            return
        start = entries[0][0]
        path = self.spool_dir / f"chunk_{start:014d}.mcap"
        future = self._executor.submit(self._write_chunk, path, entries)
        with self._lock:
            self._pending.append(future)

    def _write_chunk(self, path: Path, entries: Sequence[Entry]) -> Path:
        c = self.config
        write_mcap(path, entries, compression=c.compression, yield_gil=True, sensor_mounts=c.sensor_mounts)
        # Chunks wholly older than the window are of no more use.
        horizon = entries[-1][0] - self.config.window_us - (self.config.spool_chunk_us or 0)
        for old in sorted(self.spool_dir.glob("chunk_*.mcap")):
            if int(old.stem.split("_")[1]) < horizon:
                old.unlink(missing_ok=True)
        return path

    # --- operator summary --------------------------------------------------------------------------------
    @staticmethod
    def add_operator_summary(
        path: Path,
        text: str,
        *,
        audio: bytes | None = None,
        audio_media_type: str = "audio/wav",
        at_us: int | None = None,
    ) -> Path:
        """Add the operator's written (and optionally spoken) summary to a finished dump.

        MCAP files are append-only once finished, so the file is rewritten with an extra metadata record
        ``operator_summary`` (and an attachment for the audio), then atomically replaced.
        """
        src = Path(path)
        tmp = src.with_name(src.name + ".summary.part")
        with open(src, "rb") as fin, open(tmp, "wb") as fout:
            reader = make_reader(fin)
            header = reader.get_header()
            w = Writer(fout)
            w.start(profile=header.profile, library=header.library)
            schema_ids: dict[int, int] = {}
            channel_ids: dict[int, int] = {}
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                if schema is not None and schema.id not in schema_ids:
                    schema_ids[schema.id] = w.register_schema(
                        name=schema.name, encoding=schema.encoding, data=schema.data
                    )
                if channel.id not in channel_ids:
                    channel_ids[channel.id] = w.register_channel(
                        topic=channel.topic,
                        message_encoding=channel.message_encoding,
                        schema_id=schema_ids[schema.id] if schema is not None else 0,
                        metadata=dict(channel.metadata),
                    )
                w.add_message(
                    channel_ids[channel.id],
                    log_time=message.log_time,
                    data=message.data,
                    publish_time=message.publish_time,
                    sequence=message.sequence,
                )
            for meta in reader.iter_metadata():
                w.add_metadata(meta.name, dict(meta.metadata))
            for att in reader.iter_attachments():
                w.add_attachment(att.create_time, att.log_time, att.name, att.media_type, att.data)
            t_ns = (at_us or 0) * 1000
            w.add_metadata(SUMMARY_METADATA, {"text": text, "has_audio": str(audio is not None).lower()})
            if audio is not None:
                w.add_attachment(t_ns, t_ns, "operator_summary", audio_media_type, audio)
            w.finish()
        os.replace(tmp, src)
        return src


def install_sigterm_handler(black_box: BlackBox, on_exit: Callable[[], None] | None = None) -> None:
    """On SIGTERM: finish pending writes, dump the window synchronously, then exit with status 143.

    Must be called from the main thread (Python runs signal handlers there).
    """

    def handler(signum: int, frame: FrameType | None) -> None:
        try:
            black_box.flush(timeout_s=10.0)
        finally:
            black_box.dump("sigterm", reason=f"signal {signal.Signals(signum).name}")
            if on_exit is not None:
                on_exit()
            raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, handler)
