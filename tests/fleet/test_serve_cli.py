"""``lastmile serve``: a bad port, address or database is one line and a non-zero exit, and a database
password never appears in what it prints."""

from __future__ import annotations

import socket
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import sqlalchemy as sa

from lastmile.fleet import storage


@dataclass(frozen=True, slots=True)
class Outcome:
    returncode: int
    stdout: str
    stderr: str


def _serve(tmp_path: Path, *args: str) -> Outcome:
    """``lastmile serve`` in this process (every case here fails before uvicorn would start)."""
    from typer.testing import CliRunner

    from lastmile.cli import app

    result = CliRunner().invoke(app, ["serve", "--out", str(tmp_path), *args])
    return Outcome(result.exit_code, result.stdout, result.stderr)


def _serve_process(tmp_path: Path, *args: str) -> Outcome:
    """``lastmile serve`` as its own process, for cases a broken check would turn into a server that
    runs for ever (main listened on 4464 for --port 70000): still running after 30 s is a failure."""
    cmd = [sys.executable, "-c", "from lastmile.cli import main; main()", "serve", "--out", str(tmp_path)]
    try:
        res = subprocess.run(cmd + list(args), capture_output=True, text=True, timeout=30, check=False)
    except subprocess.TimeoutExpired as exc:
        return Outcome(-1, str(exc.stdout or ""), f"still running after 30 s: {exc.stderr!r}")
    return Outcome(res.returncode, res.stdout, res.stderr)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--port", "70000"), "expected a TCP port 1-65535, got 70000"),  # main: listened on 4464
        (("--port", "0"), "expected a TCP port 1-65535, got 0"),
        (("--port", "-1"), "expected a TCP port 1-65535, got -1"),
        (("--host", "999.1.2.3", "--port", "8080"), "expected an IP address or a resolvable name"),
    ],
)
def test_a_bad_port_or_address_is_one_line_and_exit_2(
    tmp_path: Path, args: tuple[str, ...], needle: str
) -> None:
    res = _serve_process(tmp_path, *args)
    assert res.returncode == 2
    assert needle in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert res.stdout == ""


def test_a_port_in_use_is_one_line(tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        res = _serve(tmp_path, "--port", str(port))
    assert res.returncode == 2
    assert f"expected to listen on 127.0.0.1:{port}" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def test_a_database_password_never_appears_in_errors(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nothing listens there
    res = _serve(tmp_path, "--port", "8089", "--db", f"postgresql://fleet:Hunter2pw@127.0.0.1:{port}/x")
    assert res.returncode == 2
    assert "Hunter2pw" not in res.stderr + res.stdout
    assert "fleet:***@127.0.0.1" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    bad = _serve(tmp_path, "--port", "8089", "--db", "postgresql://fleet:Hunter2pw@127.0.0.1:notaport/x")
    assert bad.returncode == 2 and "Hunter2pw" not in bad.stderr + bad.stdout, bad.stderr


def test_a_missing_sqlite_folder_is_one_line(tmp_path: Path) -> None:
    res = _serve(tmp_path, "--port", "8089", "--db", f"sqlite:///{tmp_path}/no/such/dir/x.db")
    assert res.returncode == 2
    assert "expected to connect" in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_redact_url_hides_only_the_password() -> None:
    assert storage.redact_url("postgresql://u:p%40ss@h:5432/db") == "postgresql://u:***@h:5432/db"
    assert storage.redact_url("sqlite:////tmp/x.db") == "sqlite:////tmp/x.db"
    assert "pw" not in storage.redact_url("postgresql://u:pw@h:notaport/db")


def test_the_listening_socket_is_exactly_the_port_asked_for() -> None:
    from lastmile.fleet.serve_main import listen_socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sock = listen_socket("127.0.0.1", port)
    try:
        assert sock.getsockname() == ("127.0.0.1", port)
    finally:
        sock.close()


@pytest.mark.parametrize("inline", [False, True])
def test_an_old_database_gets_its_idempotency_keys_scoped_per_rider(tmp_path: Path, inline: bool) -> None:
    """A database made before this change has client_ref unique on its own; it is upgraded at start.
    SQLAlchemy wrote that constraint as ``UNIQUE (client_ref)``; a column's inline UNIQUE is the same."""
    engine = storage.make_engine(f"sqlite:///{tmp_path / 'old.db'}")
    unique = " UNIQUE" if inline else ""
    cols = ", ".join(
        f"{c.name} {c.type.compile(engine.dialect)}" + (unique if c.name == "client_ref" else "")
        for c in storage.ride_requests.columns
    ) + ("" if inline else ", UNIQUE (client_ref)")
    row = {c.name: None for c in storage.ride_requests.columns} | {
        "id": "r1",
        "client_ref": "k",
        "rider": "alice",
        "origin": "S1",
        "destination": "S2",
        "seats": 1,
        "state": "waiting",
        "created_us": 1,
    }
    with engine.begin() as conn:
        conn.exec_driver_sql(f"CREATE TABLE ride_requests ({cols}, PRIMARY KEY (id))")
        conn.exec_driver_sql("CREATE INDEX ix_ride_requests_state ON ride_requests (state)")
        conn.execute(storage.ride_requests.insert(), row)
    with engine.begin() as conn:
        assert storage.scope_idempotency_keys(conn) is True
    with engine.begin() as conn:
        assert storage.scope_idempotency_keys(conn) is False  # once only
        conn.execute(storage.ride_requests.insert(), row | {"id": "r2", "rider": "bob"})
        assert conn.execute(sa.text("SELECT count(*) FROM ride_requests")).scalar_one() == 2
    with pytest.raises(sa.exc.IntegrityError), engine.begin() as conn:
        conn.execute(storage.ride_requests.insert(), row | {"id": "r3"})
    engine.dispose()


def test_log_records_holding_the_password_are_redacted() -> None:
    import logging

    from lastmile.fleet.serve_main import _RedactFilter

    record = logging.LogRecord(
        "x", logging.WARNING, __file__, 1, "connect to %s failed", ("u:Hunter2pw@h",), None
    )
    assert _RedactFilter("Hunter2pw").filter(record) is True
    assert record.getMessage() == "connect to u:***@h failed"
    try:
        raise RuntimeError("auth failed for Hunter2pw")
    except RuntimeError:
        import sys

        failed = logging.LogRecord("x", logging.ERROR, __file__, 1, "startup", None, sys.exc_info())
    _RedactFilter("Hunter2pw").filter(failed)
    assert failed.exc_info is None and "Hunter2pw" not in failed.getMessage()
