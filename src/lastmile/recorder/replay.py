"""Read a black-box MCAP back into our messages and Foxglove views: summary, frames for re-running the stack.

Any MCAP with Foxglove's protobuf schemas is read too (``lastmile perceive``'s output); its channels come
back as views. Rendering is in ``replay_render.py``.
"""

from __future__ import annotations

import base64
import json
import struct
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
from mcap import records as mcap_records
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory

from lastmile.core.frame_kinds import FRAME_KINDS
from lastmile.core.sensor_frames import LidarSweep, SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.recorder import mcap_codec
from lastmile.recorder.black_box import SUMMARY_METADATA
from lastmile.recorder.mcap_codec import RecordingError
from lastmile.recorder.mcap_dump import EVENT_SCHEMA, PROFILE

_SENSOR_TYPES = tuple(FRAME_KINDS)
"""Every frame type the loop delivers to the stack (the operator's input and V2I reports among them)."""


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
        attachments: (name, media type, bytes), e.g. the operator's summary as text and as sound.
        views: the decoded Foxglove (protobuf) messages in log-time order: poses, transforms, clouds,
            scene updates, logs (what replay draws; every channel of a Foxglove MCAP from elsewhere).
        warning: set when the file was cut short or damaged and only read up to the damage.
    """

    path: Path
    messages: tuple[RecordedMessage, ...]
    channels: tuple[ChannelSummary, ...]
    events: tuple[dict[str, str], ...] = ()
    metadata: tuple[tuple[str, dict[str, str]], ...] = ()
    attachments: tuple[tuple[str, str, bytes], ...] = field(default_factory=tuple)
    views: tuple[ViewMessage, ...] = ()
    warning: str | None = None

    @property
    def span_us(self) -> tuple[int, int]:
        """(first, last) log time of the lossless records, or of the views in a file that has none."""
        msgs = self.messages or self.views
        if not msgs:
            return (0, 0)
        return msgs[0].log_time_us, msgs[-1].log_time_us

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
            if isinstance(m.message, _SENSOR_TYPES):
                grouped.setdefault(m.log_time_us, []).append(cast(SensorFrame, m.message))
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
        frames = [cast(SensorFrame, m.message) for m in self.messages if isinstance(m.message, _SENSOR_TYPES)]
        return sorted(frames, key=lambda f: int(f.stamp))


@dataclass(frozen=True, slots=True)
class ViewMessage:
    """A decoded Foxglove message (protobuf): the views replay draws, and any Foxglove MCAP's channels."""

    log_time_us: int
    topic: str
    schema: str
    message: Any


class _Collector:
    """Turns (schema, channel, message) records into a :class:`Recording`'s parts."""

    def __init__(self, profile: str) -> None:
        self.ours = profile == PROFILE
        self.decoders = DecoderFactory()
        self.decode_cache: dict[int, Any] = {}
        self.messages: list[RecordedMessage] = []
        self.views: list[ViewMessage] = []
        self.counts: Counter[tuple[str, str]] = Counter()
        self.first: dict[tuple[str, str], int] = {}
        self.last: dict[tuple[str, str], int] = {}
        self.events: list[dict[str, str]] = []

    def _decoder(self, schema: Any, channel: Any) -> Any:
        if channel.id not in self.decode_cache:
            self.decode_cache[channel.id] = self.decoders.decoder_for(channel.message_encoding, schema)
        return self.decode_cache[channel.id]

    def add(self, schema: Any, channel: Any, message: Any) -> None:
        name = schema.name if schema is not None else ""
        key = (channel.topic, name)
        t_us = message.log_time // 1000
        self.counts[key] += 1
        self.first.setdefault(key, t_us)
        self.last[key] = t_us
        topic = channel.topic
        if name == EVENT_SCHEMA:
            self.events.append({k: str(v) for k, v in json.loads(message.data).items()})
        elif name.startswith("lastmile."):
            self.messages.append(RecordedMessage(t_us, topic, mcap_codec.decode_message(name, message.data)))
        elif name.startswith("foxglove.") and channel.message_encoding == "json":
            # Recordings of lastmile before the Foxglove SDK: JSON views, the LiDAR cloud among them.
            if name == mcap_codec.LIDAR_SCHEMA and topic.startswith("/sensors/lidar/"):
                self.messages.append(RecordedMessage(t_us, topic, _legacy_lidar(message.data)))
        elif name.startswith("foxglove."):
            decoder = self._decoder(schema, channel)
            if decoder is None:
                return
            decoded = decoder(message.data)
            self.views.append(ViewMessage(t_us, topic, name, decoded))
            if self.ours and name == mcap_codec.LIDAR_SCHEMA and topic.startswith("/sensors/lidar/"):
                self.messages.append(RecordedMessage(t_us, topic, mcap_codec.lidar_from_cloud(decoded)))

    def recording(
        self,
        path: Path,
        metadata: tuple[tuple[str, dict[str, str]], ...],
        attachments: tuple[tuple[str, str, bytes], ...],
        warning: str | None = None,
    ) -> Recording:
        channels = tuple(
            ChannelSummary(topic=t, schema=s, count=n, first_us=self.first[(t, s)], last_us=self.last[(t, s)])
            for (t, s), n in sorted(self.counts.items())
        )
        return Recording(
            path=path,
            messages=tuple(sorted(self.messages, key=lambda m: m.log_time_us)),
            channels=channels,
            events=tuple(self.events),
            metadata=metadata,
            attachments=attachments,
            views=tuple(sorted(self.views, key=lambda m: m.log_time_us)),
            warning=warning,
        )


def _legacy_lidar(data: bytes) -> LidarSweep:
    doc = json.loads(data)
    k = len(doc["fields"])
    pts = np.frombuffer(base64.b64decode(doc["data"]), dtype="<f4").reshape(-1, k).astype(np.float32)
    t = doc["timestamp"]
    return LidarSweep(
        stamp=Stamp(int(t["sec"]) * 1_000_000 + int(t["nsec"]) // 1000), sensor_id=doc["frame_id"], points=pts
    )


def _load_stream(path: Path, stream: Any) -> Recording:
    reader = make_reader(stream)
    col = _Collector(reader.get_header().profile)
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        col.add(schema, channel, message)
    metadata = tuple((m.name, dict(m.metadata)) for m in reader.iter_metadata())
    attachments = tuple((a.name, a.media_type, bytes(a.data)) for a in reader.iter_attachments())
    return col.recording(path, metadata, attachments)


def _recover(path: Path, stream: Any, cause: Exception) -> Recording:
    """Read a file cut short (a crash, a full disk, a copy interrupted) as far as its records are whole.

    The stream reader walks the records from the start; everything in the complete records before the
    damage is kept (messages of an unfinished chunk are lost with it).
    """
    stream.seek(0)
    reader = StreamReader(stream, record_size_limit=None)
    schemas: dict[int, mcap_records.Schema] = {}
    channels: dict[int, mcap_records.Channel] = {}
    metadata: list[tuple[str, dict[str, str]]] = []
    attachments: list[tuple[str, str, bytes]] = []
    col: _Collector | None = None
    stop: Exception = cause
    try:
        for rec in reader.records:
            if isinstance(rec, mcap_records.Header):
                col = _Collector(rec.profile)
            elif isinstance(rec, mcap_records.Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, mcap_records.Channel):
                channels[rec.id] = rec
            elif isinstance(rec, mcap_records.Message) and col is not None and rec.channel_id in channels:
                channel = channels[rec.channel_id]
                col.add(schemas.get(channel.schema_id), channel, rec)
            elif isinstance(rec, mcap_records.Metadata):
                metadata.append((rec.name, dict(rec.metadata)))
            elif isinstance(rec, mcap_records.Attachment):
                attachments.append((rec.name, rec.media_type, bytes(rec.data)))
            elif isinstance(rec, mcap_records.Footer):
                break
    except _READ_ERRORS as exc:
        stop = exc
    if col is None:
        raise RecordingError(
            f"expected a readable MCAP file, got {path}: {type(cause).__name__}: {cause}"
        ) from None
    size = path.stat().st_size
    n = sum(col.counts.values())
    warning = (
        f"{path} is cut short or damaged ({type(stop).__name__} within {size} bytes): "
        f"read the {n} messages of its complete records"
    )
    return col.recording(path, tuple(metadata), tuple(attachments), warning)


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The 8 bytes every MCAP file starts with (format version 0)."""

_READ_ERRORS = (McapError, ValueError, KeyError, EOFError, OSError, struct.error, IndexError)


def read_recording(path: str | Path) -> Recording:
    """Read a black-box MCAP file (or any Foxglove MCAP), or a spool directory of chunk files (merged).

    A file cut short is read as far as its records are whole, with ``Recording.warning`` saying so.

    Raises:
        RecordingError: the path is missing, not an MCAP file, or holds undecodable data.
    """
    p = Path(path)
    if p.is_dir():
        chunks = sorted(p.glob("chunk_*.mcap"))
        if not chunks:
            raise RecordingError(f"expected an MCAP file or a spool directory with chunk_*.mcap, got {p}")
        parts = [read_recording(c) for c in chunks]
        msgs = tuple(sorted((m for r in parts for m in r.messages), key=lambda m: m.log_time_us))
        views = tuple(sorted((m for r in parts for m in r.views), key=lambda m: m.log_time_us))
        chans = tuple(c for r in parts for c in r.channels)
        return Recording(path=p, messages=msgs, channels=_merge_channels(chans), views=views)
    if not p.is_file():
        raise RecordingError(f"expected an MCAP file, got {p} (no such file)")
    try:
        with open(p, "rb") as fh:
            if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise RecordingError(
                    f"expected a readable MCAP file, got {p}, which lacks MCAP's magic bytes"
                )
            fh.seek(0)
            try:
                return _load_stream(p, fh)
            except _READ_ERRORS as exc:
                # Truncated or damaged bytes surface from the mcap reader as any of these.
                return _recover(p, fh, exc)
    except OSError as exc:
        raise RecordingError(f"expected a readable MCAP file, got {p}: {exc}") from None


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
