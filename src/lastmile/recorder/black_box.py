"""The black box: a rolling window of what the stack received, decided and commanded -> MCAP on a trigger.

WATonoBus keeps the last 30 s and, when the operator takes over, stores them with room for the operator's
spoken summary. Here any trigger (takeover, emergency stop, MRM, collision, crash) does the same, and
triggers close in time make one file. Recording is a deque append of references to immutable messages;
a dump copies the deque (references only) and a single background thread encodes and writes the file,
so the control loop never waits for the disk.
"""

from __future__ import annotations

import json
import os
import signal
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.writer import Writer

from lastmile.core.errors import ConfigError
from lastmile.recorder import foxglove_views as fv
from lastmile.recorder.mcap_dump import (
    EVENT_METADATA,
    EVENT_SCHEMA,
    EVENT_TOPIC,
    PROFILE,
    Entry,
    write_mcap,
)
from lastmile.recorder.topic_recorder import TopicRecorder, sensor_topic

__all__ = [
    "EVENT_METADATA",
    "EVENT_SCHEMA",
    "EVENT_TOPIC",
    "PROFILE",
    "TRIGGERS",
    "BlackBox",
    "BlackBoxConfig",
    "Entry",
    "install_sigterm_handler",
    "sensor_topic",
    "write_mcap",
]

TRIGGERS = ("takeover", "emergency_stop", "mrm", "collision", "crash", "watchdog", "sigterm", "manual")
"""Trigger kinds; ``crash`` and ``sigterm`` are written synchronously (the process is going away)."""

SUMMARY_METADATA = "operator_summary"
SUMMARY_TEXT_ATTACHMENT = "operator_summary.txt"
SUMMARY_AUDIO_ATTACHMENT = "operator_summary"


@dataclass(frozen=True, slots=True, kw_only=True)
class BlackBoxConfig:
    """Attributes:
    out_dir: where dumps go (created on demand); files are ``blackbox_<trigger>_<t>s_<n>.mcap``.
    window_us: the rolling window: a dump holds the entries with log time in
        (first trigger - window, first trigger + merge].
    merge_us: triggers of any kind within this time of a dump's first trigger go into the same file
        (a takeover and an e-stop 90 ms apart are one incident); the file is written once it has passed,
        so it also holds what followed the first trigger.
    cooldown_us: a trigger of a kind already in a written dump less than this long ago adds no file
        (a collision reported on consecutive ticks makes one file).
    spool_chunk_us: if set, the window is also written continuously as finalized MCAP chunks of this
        length under ``out_dir/spool``, so even SIGKILL leaves all but the last chunk readable.
    compression: MCAP chunk compression ("zstd", "lz4" or "none").
    sensor_mounts: (4, 4) base_from_sensor transform of every sensor by frame id (``lidar_front``,
        ``radar_rear``, ``camera_front``, ``light_camera_front``), published on ``/tf``.
    map_lines: HD-map polylines ((N, 2), map frame) written around the window's poses on ``/map``.
    route: the service route's centre line ((N, 2), map frame) written on ``/route``.
    metadata: metadata records written into every file (name -> string map), e.g. what produced the run.
    """

    out_dir: Path
    window_us: int = 30_000_000
    merge_us: int = 2_000_000
    cooldown_us: int = 5_000_000
    spool_chunk_us: int | None = None
    compression: str = "zstd"
    sensor_mounts: Mapping[str, np.ndarray] = field(default_factory=dict)
    map_lines: tuple[np.ndarray, ...] = ()
    route: np.ndarray | None = None
    metadata: Mapping[str, Mapping[str, str]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.window_us <= 0:
            raise ConfigError(f"BlackBoxConfig.window_us: expected > 0, got {self.window_us}")
        if self.merge_us < 0:
            raise ConfigError(f"BlackBoxConfig.merge_us: expected >= 0, got {self.merge_us}")
        if self.spool_chunk_us is not None and not 0 < self.spool_chunk_us <= self.window_us:
            raise ConfigError(
                f"BlackBoxConfig.spool_chunk_us: expected in (0, window_us], got {self.spool_chunk_us}"
            )
        if self.compression not in ("zstd", "lz4", "none"):
            raise ConfigError(
                f"BlackBoxConfig.compression: expected zstd, lz4 or none, got {self.compression!r}"
            )
        for fid, m in self.sensor_mounts.items():
            if np.shape(m) != (4, 4):
                raise ConfigError(
                    f"BlackBoxConfig.sensor_mounts[{fid!r}]: expected a (4, 4) transform, "
                    f"got shape {np.shape(m)}"
                )

    def views(self) -> fv.ViewBuilder:
        """A fresh view builder for one file."""
        return fv.ViewBuilder(sensor_mounts=self.sensor_mounts, map_lines=self.map_lines, route=self.route)


@dataclass(slots=True)
class _OpenDump:
    """A dump whose merge time has not passed yet: triggers still join it."""

    kind: str
    first_us: int
    due_us: int
    events: list[dict[str, Any]]
    future: Future[Path]


class BlackBox(TopicRecorder):
    """Rolling window of the stack's inputs, decisions and outputs; dumps it to MCAP on triggers.

    Wiring (one call per tick from the loop, after the stack and the safety gate; see README.md):
    ``record_frames(now, frames)``, ``record_output(now, output)`` and ``record(now, topic, msg)`` for
    anything else (tracks, trajectory, health, safety directive, gated command). Call
    ``trigger(kind, now, reason)`` on a takeover / e-stop / collision and ``dump("crash", ...)`` from the
    runner's exception handler.
    """

    def __init__(self, config: BlackBoxConfig) -> None:
        super().__init__()
        self.config = config
        self._window: deque[Entry] = deque()
        self._newest_us = 0
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="black-box")
        # Start the writer thread now: spawning it inside the first trigger would cost the loop ~ms.
        self._executor.submit(lambda: None).result()
        self._pending: list[Future[Path]] = []
        self._open: _OpenDump | None = None
        self._last_written: dict[str, tuple[int, Future[Path]]] = {}
        self._count = 0
        self._lock = threading.Lock()  # only around the counter and pending list (both threads touch them)
        self._spool_entries: list[Entry] = []
        self._spool_start_us: int | None = None
        self.dumps: list[Path] = []
        """Files written so far (dumps, not spool chunks), in completion order."""
        self.dump_triggers: dict[Path, tuple[str, ...]] = {}
        """The trigger kinds each dump holds, in trigger order."""

    # --- recording (every tick, must be cheap) ------------------------------------------------------
    def record(self, now_us: int, topic: str, message: Any) -> None:
        """Keep a reference to ``message`` (an immutable core message) under ``topic`` at ``now_us``."""
        entry = (now_us, topic, message)
        window = self._window
        if now_us > self._newest_us:
            # Trim before appending: a SIGTERM handler that dumps while this call is interrupted then
            # sees the window of the previous tick, never the new entry beside the oldest expired one.
            self._newest_us = now_us
            opened = self._open
            if opened is not None and now_us > opened.due_us:
                self._submit_open()
            # An open dump still needs the window before its first trigger.
            horizon = now_us - self.config.window_us - (self.config.merge_us if self._open else 0)
            while window and window[0][0] <= horizon:
                window.popleft()
        window.append(entry)
        if self.config.spool_chunk_us is not None:
            self._spool(entry)

    def window(self) -> tuple[Entry, ...]:
        """A snapshot of the window: the entries of the last ``window_us`` (references only)."""
        horizon = self._newest_us - self.config.window_us
        return tuple(e for e in self._window if e[0] > horizon)

    # --- dumping ----------------------------------------------------------------------------------------
    def _path(self, kind: str, now_us: int) -> Path:
        with self._lock:
            self._count += 1
            n = self._count
        return self.config.out_dir / f"blackbox_{kind}_{now_us / 1e6:09.2f}s_{n:03d}.mcap"

    @staticmethod
    def _event(kind: str, now_us: int, reason: str, extra: dict[str, Any] | None) -> dict[str, Any]:
        if kind not in TRIGGERS:
            raise ConfigError(f"BlackBox trigger: expected one of {TRIGGERS}, got {kind!r}")
        ev: dict[str, Any] = {"trigger": kind, "time_us": int(now_us), "reason": reason}
        if extra:
            ev["extra"] = json.dumps(extra, default=str)
        return ev

    def trigger(
        self, kind: str, now_us: int, reason: str, extra: dict[str, Any] | None = None
    ) -> Future[Path]:
        """Mark an incident; its file is written on the background thread once ``merge_us`` has passed.

        Triggers of any kind within ``merge_us`` of the open dump's first trigger join it (each a
        separate event); a trigger of a kind written less than ``cooldown_us`` ago returns that file's
        future. Returns at once.
        """
        ev = self._event(kind, now_us, reason, extra)
        opened = self._open
        if opened is not None and now_us - opened.first_us <= self.config.merge_us:
            if not any(e["trigger"] == kind and e["reason"] == reason for e in opened.events):
                opened.events.append(ev)
            return opened.future
        last = self._last_written.get(kind)
        if last is not None and now_us - last[0] < self.config.cooldown_us:
            return last[1]
        if opened is not None:
            self._submit_open()
        future: Future[Path] = Future()
        self._open = _OpenDump(kind, int(now_us), int(now_us) + self.config.merge_us, [ev], future)
        with self._lock:
            self._pending.append(future)
        if self.config.merge_us == 0:
            self._submit_open()
        return future

    def _take_open(self) -> tuple[_OpenDump, tuple[Entry, ...]] | None:
        opened, self._open = self._open, None
        if opened is None:
            return None
        horizon = opened.first_us - self.config.window_us
        snapshot = tuple(e for e in self._window if e[0] > horizon)
        for ev in opened.events:
            self._last_written[ev["trigger"]] = (ev["time_us"], opened.future)
        return opened, snapshot

    def _submit_open(self) -> None:
        taken = self._take_open()
        if taken is None:
            return
        opened, snapshot = taken
        path = self._path(opened.kind, opened.first_us)

        def run() -> None:
            try:
                opened.future.set_result(self._write(path, snapshot, opened.events))
            except BaseException as exc:  # the future carries it to whoever waits
                opened.future.set_exception(exc)

        self._executor.submit(run)

    def dump(self, kind: str = "crash", reason: str = "", now_us: int | None = None) -> Path:
        """Write the window now, in the calling thread (for a crash or SIGTERM: no thread to rely on).

        A dump still open joins it: its events go into this file and its future gets this path.
        """
        t = self._newest_us if now_us is None else now_us
        ev = self._event(kind, t, reason, None)
        taken = self._take_open()
        events = [*taken[0].events, ev] if taken is not None else [ev]
        horizon = min(t, taken[0].first_us if taken else t) - self.config.window_us
        entries = tuple(e for e in self._window if e[0] > horizon)
        path = self._write(self._path(kind, t), entries, events, background=False)
        if taken is not None:
            taken[0].future.set_result(path)
        return path

    def _write(
        self, path: Path, entries: Sequence[Entry], events: list[dict[str, Any]], background: bool = True
    ) -> Path:
        c = self.config
        bounds = {"window_start_us": entries[0][0], "window_end_us": entries[-1][0]} if entries else {}
        out = write_mcap(
            path,
            entries,
            views=c.views(),
            events=[{**ev, **bounds} for ev in events],
            metadata={k: dict(v) for k, v in c.metadata.items()},
            compression=c.compression,
            yield_gil=background,
        )
        with self._lock:
            self.dumps.append(out)
            self.dump_triggers[out] = tuple(ev["trigger"] for ev in events)
        return out

    def flush(self, timeout_s: float | None = None) -> list[Path]:
        """Write a dump still merging now and wait for every background write; returns their files."""
        self._submit_open()
        with self._lock:
            pending, self._pending = self._pending, []
        return [f.result(timeout=timeout_s) for f in pending]

    def close(self) -> None:
        """Write a dump still merging, finish pending writes and the current spool chunk, stop the thread."""
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
        meta = {k: dict(v) for k, v in c.metadata.items()}
        write_mcap(path, entries, views=c.views(), metadata=meta, compression=c.compression, yield_gil=True)
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
        """Attach the operator's written (and optionally spoken) summary to a finished dump (WATonoBus).

        The text becomes an attachment ``operator_summary.txt`` (text/plain, UTF-8) and a metadata record
        ``operator_summary``; the sound an attachment ``operator_summary`` of ``audio_media_type``. MCAP
        files are append-only once finished, so the file is rewritten and atomically replaced.
        """
        src = Path(path)
        tmp = src.with_name(src.name + ".summary.part")
        with open(src, "rb") as fin, open(tmp, "wb") as fout:
            reader = make_reader(fin)
            header = reader.get_header()
            w = Writer(fout)
            w.start(profile=header.profile, library=header.library)
            _copy_records(reader, w)
            t_ns = (at_us or 0) * 1000
            w.add_metadata(SUMMARY_METADATA, {"text": text, "has_audio": str(audio is not None).lower()})
            w.add_attachment(t_ns, t_ns, SUMMARY_TEXT_ATTACHMENT, "text/plain; charset=utf-8", text.encode())
            if audio is not None:
                w.add_attachment(t_ns, t_ns, SUMMARY_AUDIO_ATTACHMENT, audio_media_type, audio)
            w.finish()
        os.replace(tmp, src)
        return src


def _copy_records(reader: Any, w: Writer) -> None:
    """Every schema, channel, message, metadata record and attachment of ``reader`` onto ``w``."""
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


AUDIO_MEDIA_TYPES = {".wav": "audio/wav", ".mp3": "audio/mpeg", ".ogg": "audio/ogg", ".flac": "audio/flac"}


def attach_operator_summary(path: Path, text: str | None, audio: Path | None = None) -> Path:
    """Check the operator's summary (text, optional sound file) and attach it to the dump at ``path``.

    Raises:
        ConfigError: no text, an audio file that is missing or of an unknown kind.
    """
    if not text or not text.strip():
        raise ConfigError(f"--summary: expected the operator's summary text, got {text!r}")
    data = None
    media_type = "audio/wav"
    if audio is not None:
        media_type = AUDIO_MEDIA_TYPES.get(audio.suffix.lower(), "")
        if not media_type:
            kinds = ", ".join(AUDIO_MEDIA_TYPES)
            raise ConfigError(
                f"--audio: expected a {kinds} file, got {audio} ({audio.suffix or 'no suffix'})"
            )
        if not audio.is_file():
            raise ConfigError(f"--audio: expected a sound file, got {audio} (no such file)")
        data = audio.read_bytes()
    if not Path(path).is_file():
        raise ConfigError(f"--summary: expected a black-box MCAP file, got {path} (no such file)")
    return BlackBox.add_operator_summary(Path(path), text.strip(), audio=data, audio_media_type=media_type)


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
