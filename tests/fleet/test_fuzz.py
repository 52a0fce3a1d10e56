"""Schemathesis fuzzes every operation of the real server's OpenAPI schema: no input makes a 5xx.

A bounded run here (seeded, a few examples per operation); ``benchmarks/fleet_fuzz.py`` runs longer."""

from __future__ import annotations

import re

from tests.fleet.conftest import ServerProcess


def test_fuzzed_requests_never_cause_a_server_error(server: ServerProcess) -> None:
    # The operator's token reaches every operation; the other roles' runs are in the longer script.
    result = server.fuzz("operator", examples=5, seed=1)
    assert result.returncode == 0, result.stdout[-3000:]
    counts = re.search(r"(\d+) generated, (\d+) passed", result.stdout)
    assert counts is not None and int(counts[1]) == int(counts[2]) > 100, result.stdout[-3000:]
    assert "Traceback" not in server.log_text()
