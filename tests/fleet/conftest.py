"""Fixtures that run the real dispatch server as a separate process (``lastmile serve``) on a free port."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from lastmile.runner import fleet_server as runner_server


class ServerProcess(runner_server.ServerProcess):
    """A running ``lastmile serve`` (the fleet run's own launcher); ``tokens`` are the ones it wrote
    at its first start. Adds what the tests need: the fuzzer and authenticated clients."""

    def log_text(self) -> str:
        return self.log_tail()

    def fuzz(
        self, role: str, examples: int, seed: int, phases: str = "coverage,fuzzing"
    ) -> subprocess.CompletedProcess[str]:
        """Schemathesis against this server's OpenAPI schema with one role's token; fails on any 5xx."""
        cmd = [sys.executable, "-m", "schemathesis.cli", "run", self.url + "/openapi.json"]
        cmd += ["-H", f"Authorization: Bearer {self.tokens[role]}", "--checks", "not_a_server_error"]
        cmd += ["-n", str(examples), "--seed", str(seed), "--workers", "1", "--phases", phases]
        # Below the token's rate limit (operators 200/s), so every case reaches the route it targets
        # rather than a 429, and the shared session server's token is not left drained for later tests.
        cmd += ["--rate-limit", "150/s"]
        # cwd: schemathesis keeps a cache folder in its working directory; not in the repository.
        return subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False, cwd=self.out_dir)

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
