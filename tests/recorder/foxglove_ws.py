"""A Foxglove WebSocket client's first step, shared by the live-view tests: the advertised channels."""

from __future__ import annotations

import json
import time


def advertised(ws: object, wanted: set[str], timeout_s: float) -> dict[str, dict]:
    """The channels the server advertised, by topic, once ``wanted`` are all there or at the timeout."""
    channels: dict[str, dict] = {}
    deadline = time.monotonic() + timeout_s
    while not wanted <= set(channels) and time.monotonic() < deadline:
        msg = ws.recv(timeout=timeout_s)  # type: ignore[attr-defined]
        if isinstance(msg, str):
            doc = json.loads(msg)
            if doc.get("op") == "advertise":
                channels.update({c["topic"]: c for c in doc["channels"]})
    return channels
