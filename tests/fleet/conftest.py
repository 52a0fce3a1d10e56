"""Fixtures that run the real dispatch server as a separate process (``lastmile serve``) on a free port."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import sqlalchemy as sa

from lastmile.runner import fleet_server as runner_server
from tests.fleet.pg_cluster import ExternalPg, PgCluster, PgUnavailableError


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


@pytest.fixture(scope="session")
def postgres() -> Iterator[PgCluster | ExternalPg]:
    """A PostgreSQL server: ``LASTMILE_FLEET_PG_URL`` if set, else a private one started here."""
    pytest.importorskip("psycopg", reason="the postgres extra (psycopg) is not installed")
    external = os.environ.get("LASTMILE_FLEET_PG_URL")
    if external:
        yield ExternalPg(external)
        return
    try:
        cluster = PgCluster().start()
    except PgUnavailableError as exc:
        pytest.skip(f"no PostgreSQL to test against: {exc}")
    yield cluster
    cluster.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def durable_server(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[ServerProcess]:
    """A fresh server on each database the dispatcher supports (the durability, restart and load
    tests run on both)."""
    db_url = None
    if request.param == "postgresql":
        db_url = request.getfixturevalue("postgres").new_database()
    (tmp_path / "runs").mkdir()
    proc = ServerProcess(out_dir=tmp_path / "serve", runs_dir=tmp_path / "runs", db_url=db_url)
    proc.out_dir.mkdir()
    yield proc.start()
    proc.stop()


def db_engine(server: ServerProcess) -> sa.Engine:
    """An engine on the server's database (SQLite file in its folder, or its PostgreSQL URL)."""
    from lastmile.fleet.storage import make_engine

    return make_engine(server.db_url or f"sqlite:///{server.out_dir / 'fleet.db'}")
