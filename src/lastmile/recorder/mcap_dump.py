"""Writing one black-box file: lossless records, Foxglove views, events, metadata and attachments.

Written with the ``mcap`` library; the Foxglove channels carry ``foxglove-sdk`` messages with the
SDK's own protobuf schemas, our channels carry JSON with documented schemas (``record_schemas.py``).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from lastmile.core.vehicle_messages import LocalizationEstimate, VehicleStatus
from lastmile.recorder import foxglove_views as fv
from lastmile.recorder import mcap_codec
from lastmile.recorder.mcap_codec import ChannelSpec

PROFILE = "lastmile.black_box"
EVENT_TOPIC = "/events"
EVENT_SCHEMA = "lastmile.BlackBoxEvent"
EVENT_METADATA = "black_box_event"

EVENT_SCHEMA_BYTES = json.dumps(
    {
        "title": EVENT_SCHEMA,
        "description": "One trigger that made the black box write this file (several when triggers merged).",
        "type": "object",
        "properties": {
            "trigger": {
                "type": "string",
                "description": "takeover, emergency_stop, mrm, collision, crash, watchdog, sigterm or manual",
            },
            "time_us": {"type": "integer", "description": "the loop's time of the trigger (µs)"},
            "reason": {"type": "string", "description": "why, in the words of whoever triggered"},
            "window_start_us": {"type": "integer", "description": "the oldest record's log time (µs)"},
            "window_end_us": {"type": "integer", "description": "the newest record's log time (µs)"},
            "extra": {"type": "string", "description": "JSON of any further details"},
        },
        "required": ["trigger", "time_us", "reason"],
    },
    separators=(",", ":"),
).encode()
_EVENT_SPEC = ChannelSpec(EVENT_SCHEMA, "jsonschema", EVENT_SCHEMA_BYTES, "json")

_YIELD_EVERY_S = 0.001

Entry = tuple[int, str, Any]
"""(log time in microseconds, topic, message): what the window holds."""


@dataclass(frozen=True, slots=True)
class Attachment:
    """A file attached to a recording (the operator's summary as text or sound)."""

    name: str
    media_type: str
    data: bytes
    log_time_us: int = 0


def compression_type(name: str) -> CompressionType:
    return {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[name]


class _Out:
    """Adds messages to a writer, registering each (topic, schema) once and numbering them in order."""

    def __init__(self, writer: Writer) -> None:
        self.w = writer
        self.schemas: dict[str, int] = {}
        self.channels: dict[tuple[str, str], int] = {}
        self.seq = 0

    def _id(self, topic: str, spec: ChannelSpec) -> int:
        key = (topic, spec.schema)
        cid = self.channels.get(key)
        if cid is None:
            sid = self.schemas.get(spec.schema)
            if sid is None:
                sid = self.w.register_schema(
                    name=spec.schema, encoding=spec.schema_encoding, data=spec.schema_data
                )
                self.schemas[spec.schema] = sid
            cid = self.w.register_channel(topic=topic, message_encoding=spec.message_encoding, schema_id=sid)
            self.channels[key] = cid
        return cid

    def add(self, topic: str, spec: ChannelSpec, data: bytes, log_us: int, publish_us: int) -> None:
        self.w.add_message(
            self._id(topic, spec),
            log_time=log_us * 1000,
            data=data,
            publish_time=max(publish_us, 0) * 1000,  # MCAP times are unsigned
            sequence=self.seq,
        )
        self.seq += 1

    def add_view(self, topic: str, msg: Any, log_us: int, publish_us: int) -> None:
        self.add(topic, mcap_codec.foxglove_spec(msg), msg.encode(), log_us, publish_us)

    def add_event(self, ev: dict[str, Any]) -> None:
        """A trigger: its ``/events`` record, a ``/log`` line and a ``black_box_event`` metadata record."""
        t_us = int(ev["time_us"])
        self.add(EVENT_TOPIC, _EVENT_SPEC, json.dumps(ev).encode(), t_us, t_us)
        severe = ev["trigger"] in ("crash", "collision", "emergency_stop")
        level = fv.fm.LogLevel.Error if severe else fv.fm.LogLevel.Warning
        text = f"black box trigger {ev['trigger']}: {ev['reason']}"
        self.add_view(fv.LOG_TOPIC, fv.log(t_us, level, "black_box", text), t_us, t_us)
        self.w.add_metadata(EVENT_METADATA, {k: str(v) for k, v in ev.items()})


def poses_xy(entries: Iterable[Entry]) -> np.ndarray:
    """(N, 2) ego positions the window knows (the stack's estimates, else its status reports)."""
    est = [
        (m.map_from_base.x_m, m.map_from_base.y_m)
        for _, _, m in entries
        if isinstance(m, LocalizationEstimate) and m.valid
    ]
    if not est:
        est = [
            (m.map_from_base.x_m, m.map_from_base.y_m)
            for _, _, m in entries
            if isinstance(m, VehicleStatus) and m.map_from_base is not None
        ]
    return np.asarray(est, dtype=float).reshape(-1, 2)


def write_mcap(
    path: Path,
    entries: Sequence[Entry],
    *,
    views: fv.ViewBuilder | None = None,
    events: Sequence[dict[str, Any]] = (),
    metadata: dict[str, dict[str, str]] | None = None,
    attachments: Sequence[Attachment] = (),
    compression: str = "zstd",
    yield_gil: bool = False,
) -> Path:
    """Write entries, their Foxglove views and the events to ``path`` atomically (temporary name, rename).

    With ``yield_gil`` (background writes) the thread gives up the GIL after every millisecond of
    work, so a busy loop waits about that long instead of the interpreter's 5 ms switch interval.

    Returns:
        ``path``; a reader never sees a half-written file under that name.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as fh:
        w = Writer(fh, compression=compression_type(compression))
        w.start(profile=PROFILE, library="lastmile")
        out = _Out(w)
        if views is not None and entries:
            t0 = entries[0][0]
            for topic, msg in views.opening(t0, poses_xy(entries)):
                out.add_view(topic, msg, t0, t0)
        last_yield = time.perf_counter()
        for log_us, topic, msg in entries:
            stamp_us = int(getattr(msg, "stamp", log_us))
            spec, data = mcap_codec.lossless_record(msg)
            out.add(topic, spec, data, log_us, stamp_us)
            if views is not None:
                for view_topic, view in views.views(log_us, topic, msg):
                    out.add_view(view_topic, view, log_us, stamp_us)
            if yield_gil and time.perf_counter() - last_yield > _YIELD_EVERY_S:
                time.sleep(0)
                last_yield = time.perf_counter()
        for ev in events:
            out.add_event(ev)
        for meta_name, meta in (metadata or {}).items():
            w.add_metadata(meta_name, meta)
        for att in attachments:
            t_ns = att.log_time_us * 1000
            w.add_attachment(t_ns, t_ns, att.name, att.media_type, att.data)
        w.finish()
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path
