"""The dispatch server as a child process of a fleet run (``lastmile serve`` on a free loopback port)."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Self

import httpx

from lastmile.core.errors import ConfigError

START_TIMEOUT_S = 30.0


def free_port() -> int:
    """A TCP port nobody listens on right now (the OS picks it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class ServerProcess:
    """``lastmile serve`` with its database (SQLite in ``out_dir`` unless ``db_url``) and tokens in
    ``out_dir``; the timetable clock is off (the run's shuttles get only the rides its riders ask for).
    The fleet tests run the server through this class too."""

    def __init__(
        self, out_dir: Path, runs_dir: Path, db_url: str | None = None, route: str | Path | None = None
    ) -> None:
        self.out_dir = out_dir
        self.runs_dir = runs_dir
        self.db_url = db_url
        self.route = route
        self.port = free_port()
        self.proc: subprocess.Popen[bytes] | None = None
        self.tokens: dict[str, str] = {}

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> Self:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-c", "from lastmile.cli import main; main()", "serve"]
        cmd += ["--port", str(self.port), "--out", str(self.out_dir), "--runs", str(self.runs_dir)]
        cmd += ["--timetable-lead", "0"]
        if self.db_url is not None:
            cmd += ["--db", self.db_url]
        if self.route:
            cmd += ["--route", str(self.route)]
        with open(self.out_dir / "server.log", "ab") as log:
            # Its own session: a Ctrl-C at the terminal reaches the fleet run, which then writes its
            # partial run directory while the server still answers, and stops the server itself.
            self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
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

    def kill(self) -> None:
        """SIGKILL: no shutdown handler runs, as in a crash or power cut of the process."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.kill()
