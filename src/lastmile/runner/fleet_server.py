"""The dispatch server as a child process of a fleet run (``lastmile serve`` on a free loopback port)."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

from lastmile.core.errors import ConfigError

START_TIMEOUT_S = 30.0


def free_port() -> int:
    """A TCP port nobody listens on right now (the OS picks it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class ServerProcess:
    """``lastmile serve`` with its SQLite database and tokens in ``out_dir``; the timetable clock is off
    (the run's shuttles get only the rides its riders ask for)."""

    def __init__(self, out_dir: Path, runs_dir: Path) -> None:
        self.out_dir = out_dir
        self.runs_dir = runs_dir
        self.port = free_port()
        self.proc: subprocess.Popen[bytes] | None = None
        self.tokens: dict[str, str] = {}

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> ServerProcess:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-c", "from lastmile.cli import main; main()", "serve"]
        cmd += ["--port", str(self.port), "--out", str(self.out_dir), "--runs", str(self.runs_dir)]
        cmd += ["--timetable-lead", "0"]
        with open(self.out_dir / "server.log", "ab") as log:
            self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise ConfigError(
                    f"dispatch server: expected it to start, it exited with {self.proc.returncode}: "
                    f"{self.log_tail()}"
                )
            try:
                if httpx.get(self.url + "/openapi.json", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        else:
            self.stop()
            raise ConfigError(
                f"dispatch server: expected it ready within {START_TIMEOUT_S} s: {self.log_tail()}"
            )
        self.tokens = json.loads((self.out_dir / "tokens.json").read_text())
        return self

    def log_tail(self) -> str:
        path = self.out_dir / "server.log"
        return path.read_text(errors="replace")[-1500:] if path.exists() else ""

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
