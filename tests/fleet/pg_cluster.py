"""A private PostgreSQL server for the fleet tests: ``initdb`` in a temporary folder, listening on a free
loopback port only, password authentication over TCP, removed at the end.

Debian's ``postgresql`` package provides the binaries (``scripts/ensure_postgres.sh`` installs it;
``test.sh`` calls that script). As root the server runs as the ``postgres`` user, since PostgreSQL
refuses to run as root. ``LASTMILE_FLEET_PG_URL`` points the tests at an existing server instead.
"""

from __future__ import annotations

import glob
import os
import pwd
import secrets
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

import sqlalchemy as sa

PASSWORD_BYTES = 12


class PgUnavailableError(Exception):
    """No PostgreSQL binaries here, or the private server would not start (the reason says which)."""


def _bindir() -> Path:
    versions = [Path(p) for p in glob.glob("/usr/lib/postgresql/*/bin") if (Path(p) / "initdb").exists()]
    if versions:
        return max(versions, key=lambda p: int(p.parent.name) if p.parent.name.isdigit() else 0)
    initdb = shutil.which("initdb")
    if initdb is None:
        raise PgUnavailableError("no initdb found (apt-get install postgresql: scripts/ensure_postgres.sh)")
    return Path(initdb).resolve().parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class PgCluster:
    """A running private cluster; ``new_database()`` gives each test an empty database of its own."""

    def __init__(self) -> None:
        self.bindir = _bindir()
        self.root = Path(tempfile.mkdtemp(prefix="lastmile-pg-"))
        self.port = _free_port()
        self.password = secrets.token_urlsafe(PASSWORD_BYTES)
        self._as: list[str] = []
        if os.geteuid() == 0:
            try:
                user = pwd.getpwnam("postgres")
            except KeyError:
                raise PgUnavailableError(
                    "running as root and there is no 'postgres' user to run the server"
                ) from None
            os.chown(self.root, user.pw_uid, user.pw_gid)
            self._as = ["runuser", "-u", "postgres", "--"]
        self._databases = 0

    def _run(self, *cmd: str) -> None:
        res = subprocess.run(self._as + list(cmd), capture_output=True, text=True, timeout=120, check=False)
        if res.returncode != 0:
            raise PgUnavailableError(
                f"{Path(cmd[0]).name} failed: {(res.stderr or res.stdout).strip()[-500:]}"
            )

    def start(self) -> PgCluster:
        pwfile = self.root / "pw"
        pwfile.write_text(self.password + "\n")
        if self._as:
            shutil.chown(pwfile, "postgres")
        data = self.root / "data"
        self._run(
            str(self.bindir / "initdb"),
            "-D",
            str(data),
            "-U",
            "postgres",
            "--pwfile",
            str(pwfile),
            "--auth-local=trust",
            "--auth-host=scram-sha-256",
            "-E",
            "UTF8",
        )
        pwfile.unlink()
        options = f"-c listen_addresses=127.0.0.1 -p {self.port} -k {self.root} -c fsync=on"
        self._run(
            str(self.bindir / "pg_ctl"),
            "-D",
            str(data),
            "-o",
            options,
            "-l",
            str(self.root / "log"),
            "-w",
            "start",
        )
        return self

    def url(self, database: str = "postgres") -> str:
        return f"postgresql://postgres:{self.password}@127.0.0.1:{self.port}/{database}"

    def new_database(self) -> str:
        """An empty database of its own; returns its URL."""
        self._databases += 1
        name = f"fleet_{self._databases}"
        engine = sa.create_engine(
            self.url().replace("postgresql://", "postgresql+psycopg://"), isolation_level="AUTOCOMMIT"
        )
        with engine.connect() as conn:
            conn.exec_driver_sql(f"CREATE DATABASE {name}")
        engine.dispose()
        return self.url(name)

    def stop(self) -> None:
        # Immediate: the folder is deleted next, so the shutdown checkpoint would be wasted I/O.
        try:
            self._run(
                str(self.bindir / "pg_ctl"), "-D", str(self.root / "data"), "-m", "immediate", "-w", "stop"
            )
        finally:
            shutil.rmtree(self.root, ignore_errors=True)


class ExternalPg:
    """``LASTMILE_FLEET_PG_URL``: an existing server where the tests may create databases."""

    def __init__(self, url: str) -> None:
        self.admin_url = url
        self.password = sa.engine.make_url(url).password or ""
        self._databases = 0

    def new_database(self) -> str:
        self._databases += 1
        name = f"fleet_test_{os.getpid()}_{self._databases}"
        admin = sa.engine.make_url(self.admin_url).set(drivername="postgresql+psycopg")
        engine = sa.create_engine(admin, isolation_level="AUTOCOMMIT")
        with engine.connect() as conn:
            conn.exec_driver_sql(f"DROP DATABASE IF EXISTS {name}")
            conn.exec_driver_sql(f"CREATE DATABASE {name}")
        engine.dispose()
        return admin.set(database=name, drivername="postgresql").render_as_string(hide_password=False)

    def stop(self) -> None:
        pass
