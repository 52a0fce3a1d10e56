"""``lastmile run --live`` from the command line: a Foxglove WebSocket client connects while the run goes,
sees the channels advertised and receives messages."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from websockets.sync.client import connect

from tests.recorder.foxglove_ws import advertised

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
"""What a Foxglove client offers: the SDK's server (foxglove-sdk 0.30) speaks the protocol under its new
name only and answers a client offering nothing but the old ``foxglove.websocket.v1`` with HTTP 400 (so
viewers older than that rename cannot connect); the protocol itself is unchanged."""

ROOT = Path(__file__).resolve().parents[2]


def _can_bind_localhost() -> bool:
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", 0))
        return True
    except OSError:
        return False


def test_a_foxglove_client_watches_a_cli_run_live(tmp_path: Path) -> None:
    if not _can_bind_localhost():
        pytest.skip("cannot bind a TCP port on 127.0.0.1 here: --live has nowhere to serve")
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT / "src"),
        "OPENBLAS_NUM_THREADS": "1",
        "PYTHONUNBUFFERED": "1",
    }
    # Port 0: the server takes any free port and the CLI prints it. 3 s simulated, paced to the clock;
    # the run is stopped once a message arrived (the report it would write next is tested elsewhere).
    args = ["run", "--live", "--live-port", "0", "--seed", "0", "--minutes", "0.05", "--perception", "radar"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "lastmile", *args, "--out", str(tmp_path / "run")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    try:
        port = _announced_port(proc)
        if port is None:
            out, err = proc.communicate(timeout=120)
            if "expected a free port" in err:
                pytest.skip(f"--live could not bind its port: {err.strip()}")
            pytest.fail(
                f"no 'live: connect Foxglove' line; exit {proc.returncode}: {out[-500:]} {err[-500:]}"
            )
        offered = SUBPROTOCOLS
        with connect(f"ws://127.0.0.1:{port}", subprotocols=offered, open_timeout=20) as ws:  # type: ignore[arg-type]
            assert ws.subprotocol == "foxglove.sdk.v1"
            channels = _advertised(ws, {"/tf", "/stack/command"})
            assert channels["/tf"]["schemaName"] == "foxglove.FrameTransforms"
            payload = _first_message(ws, channel_id=channels["/stack/command"]["id"], subscription_id=3)
        assert payload is not None, "subscribed to /stack/command but no message arrived"
        assert json.loads(payload)["$type"] == "ActuatorCommand"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _announced_port(proc: subprocess.Popen[str]) -> int | None:
    """The port in the CLI's "live: connect Foxglove to ws://127.0.0.1:PORT" line (None if it exits)."""
    found: list[int] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            m = re.search(r"live: connect Foxglove to ws://127\.0\.0\.1:(\d+)", line)
            if m:
                found.append(int(m.group(1)))
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout=120)
    return found[0] if found else None


def _advertised(ws: object, wanted: set[str], timeout_s: float = 20.0) -> dict[str, dict]:
    channels = advertised(ws, wanted, timeout_s)
    assert wanted <= set(channels), sorted(channels)
    return channels


def _first_message(ws: Any, channel_id: int, subscription_id: int, timeout_s: float = 20.0) -> bytes | None:
    """Subscribe to a channel; the payload of the first binary Message Data frame (opcode 1) it sends.

    A subscription sent right after a channel's advertisement can be refused ("Unknown channel ID",
    foxglove-sdk 0.30): it is sent again, as a viewer would on its next attempt.
    """
    subscribe = {"op": "subscribe", "subscriptions": [{"id": subscription_id, "channelId": channel_id}]}
    ws.send(json.dumps(subscribe))
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            msg = ws.recv(timeout=1.0)
        except TimeoutError:
            continue
        if isinstance(msg, str) and "Unknown channel ID" in json.loads(msg).get("message", ""):
            time.sleep(0.1)
            ws.send(json.dumps(subscribe))
            continue
        # opcode 1, subscription id (u32 LE), log time (u64 LE), then the payload.
        if isinstance(msg, bytes) and msg[0] == 1 and int.from_bytes(msg[1:5], "little") == subscription_id:
            return msg[13:]
    return None
