"""Fixtures that run the real dispatch server as a separate process (``lastmile serve``) on a free port."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest

START_TIMEOUT_S = 30.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class ServerProcess:
    """A running ``lastmile serve``; ``tokens`` are the ones it wrote at its first start."""

    out_dir: Path
    runs_dir: Path
    port: int = field(default_factory=free_port)
    proc: subprocess.Popen[bytes] | None = None
    tokens: dict[str, str] = field(default_factory=dict)
    db_url: str | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> ServerProcess:
        log = open(self.out_dir / "server.log", "ab")  # noqa: SIM115  closed with the process
        cmd = [
            sys.executable,
            "-c",
            "from lastmile.cli import main; main()",
            "serve",
            "--port",
            str(self.port),
        ]
        # No timetable clock: the tests' shuttles get only the work each test gives them.
        cmd += ["--out", str(self.out_dir), "--runs", str(self.runs_dir), "--timetable-lead", "0"]
        if self.db_url is not None:
            cmd += ["--db", self.db_url]
        self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=os.environ.copy())
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}: {self.log_text()}")
            try:
                if httpx.get(self.url + "/openapi.json", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        else:
            self.stop()
            raise RuntimeError(f"server not ready within {START_TIMEOUT_S} s: {self.log_text()}")
        self.tokens = json.loads((self.out_dir / "tokens.json").read_text())
        return self

    def log_text(self) -> str:
        return (self.out_dir / "server.log").read_text(errors="replace")[-2000:]

    def fuzz(
        self, role: str, examples: int, seed: int, phases: str = "coverage,fuzzing"
    ) -> subprocess.CompletedProcess[str]:
        """Schemathesis against this server's OpenAPI schema with one role's token; fails on any 5xx."""
        cmd = [sys.executable, "-m", "schemathesis.cli", "run", self.url + "/openapi.json"]
        cmd += ["-H", f"Authorization: Bearer {self.tokens[role]}", "--checks", "not_a_server_error"]
        cmd += ["-n", str(examples), "--seed", str(seed), "--workers", "1", "--phases", phases]
        # cwd: schemathesis keeps a cache folder in its working directory; not in the repository.
        return subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False, cwd=self.out_dir)

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

    def client(self, role: str) -> httpx.Client:
        return httpx.Client(
            base_url=self.url, headers={"Authorization": f"Bearer {self.tokens[role]}"}, timeout=10
        )


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    out = tmp_path_factory.mktemp("serve")
    runs = tmp_path_factory.mktemp("runs")
    (runs / "run-a").mkdir()
    (runs / "run-a" / "report.md").write_text("# a run\n")
    proc = ServerProcess(out_dir=out, runs_dir=runs).start()
    yield proc
    proc.stop()


@pytest.fixture
def fresh_server(tmp_path: Path) -> Iterator[ServerProcess]:
    (tmp_path / "runs").mkdir()
    proc = ServerProcess(out_dir=tmp_path / "serve", runs_dir=tmp_path / "runs")
    proc.out_dir.mkdir()
    yield proc.start()
    proc.stop()
