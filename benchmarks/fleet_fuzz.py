"""Longer fuzz of the dispatch server's OpenAPI schema with schemathesis: no input may cause a 5xx.

Run: python benchmarks/fleet_fuzz.py [--examples 100] [--json out.json]

Starts ``lastmile serve`` on a free port (a fresh SQLite database, one shuttle in service so rides get
assigned), then runs schemathesis' coverage, fuzzing and stateful phases once per role token, with the
``not_a_server_error`` check (at a pace under each role's rate limit, so cases reach their routes),
then sends every operation that takes a body the abusive bodies of issue #21 (NaN, Infinity, 1e309,
a 400-digit integer, malformed JSON, 1 MB with a Content-Length, 20 MB chunked), and finally scans
the server log for tracebacks. The bounded version of this is ``tests/fleet/test_fuzz.py``.
"""

from __future__ import annotations

import argparse
import json
import re
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from rich.console import Console
from rich.table import Table


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# Schemathesis' pace per role: under the server's per-token limits (riders 20/s, others 200/s).
FUZZ_RATE = {"operator": "150/s", "rider": "15/s", "vehicle": "150/s"}
BAD_NUMBERS = ("NaN", "Infinity", "-Infinity", "1e309", "9" * 400)


def abusive_bodies(url: str, token: str) -> dict[str, Any]:
    """Every operation with a JSON body gets each abusive body; returns status counts and 5xx cases."""
    schema = httpx.get(url + "/openapi.json").json()
    statuses: dict[str, int] = {}
    server_errors: list[str] = []
    headers = {"Authorization": f"Bearer {token}", "Content-Type": "application/json"}

    def chunked() -> Any:
        for _ in range(20_000_000 // 65_536):
            yield b"[" + b"0," * 32_767 + b"0]"

    with httpx.Client(base_url=url, headers=headers, timeout=60) as http:
        for path, ops in schema["paths"].items():
            for method, op in ops.items():
                if "requestBody" not in op:
                    continue
                concrete = re.sub(r"\{[^}]+\}", "x", path)
                bodies: list[tuple[str, Any]] = [
                    (f"number {n[:12]}", f'{{"seats": {n}, "crosswalk": {n}, "capacity": {n}}}'.encode())
                    for n in BAD_NUMBERS
                ]
                bodies += [("malformed", b'{"a": '), ("1 MB", b'{"a": "' + b"x" * 1_000_000 + b'"}')]
                bodies += [("20 MB chunked", chunked())]
                for name, content in bodies:
                    try:
                        code = str(http.request(method.upper(), concrete, content=content).status_code)
                    except httpx.TransportError:
                        code = "closed_early"
                    statuses[code] = statuses.get(code, 0) + 1
                    if code.isdigit() and int(code) >= 500:
                        server_errors.append(f"{method.upper()} {path} {name}: {code}")
    return {"statuses": statuses, "server_errors": server_errors}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--examples", type=int, default=100, help="examples per operation and phase")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/fleet_fuzz.json"))
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="fleet-fuzz-") as tmp:
        out = Path(tmp)
        (out / "runs" / "demo").mkdir(parents=True)
        (out / "runs" / "demo" / "report.md").write_text("# demo\n")
        port = free_port()
        url = f"http://127.0.0.1:{port}"
        log = open(out / "server.log", "wb")  # noqa: SIM115  lives as long as the server
        cmd = [sys.executable, "-c", "from lastmile.cli import main; main()", "serve", "--port", str(port)]
        server = subprocess.Popen(
            [*cmd, "--out", str(out), "--runs", str(out / "runs")], stdout=log, stderr=log
        )
        try:
            for _ in range(300):
                try:
                    if httpx.get(url + "/openapi.json", timeout=1).status_code == 200:
                        break
                except httpx.TransportError:
                    time.sleep(0.1)
            tokens = json.loads((out / "tokens.json").read_text())
            op = {"Authorization": f"Bearer {tokens['operator']}"}
            httpx.post(url + "/api/vehicles", json={"id": "fuzz-1"}, headers=op).raise_for_status()
            httpx.post(url + "/api/vehicles/fuzz-1/command", json={"command": "start_service"}, headers=op)
            for role in ("operator", "rider", "vehicle"):
                t0 = time.perf_counter()
                st = [sys.executable, "-m", "schemathesis.cli", "run", url + "/openapi.json"]
                st += ["-H", f"Authorization: Bearer {tokens[role]}", "--checks", "not_a_server_error"]
                st += ["-n", str(args.examples), "--seed", str(args.seed), "--workers", "1"]
                st += ["--rate-limit", FUZZ_RATE[role]]
                res = subprocess.run(st, capture_output=True, text=True, timeout=1800, check=False, cwd=out)
                counts = re.search(r"(\d+) generated, (\d+) passed", res.stdout)
                rows.append(
                    {
                        "role": role,
                        "exit_code": res.returncode,
                        "generated": int(counts[1]) if counts else None,
                        "passed": int(counts[2]) if counts else None,
                        "wall_s": time.perf_counter() - t0,
                        "tail": res.stdout[-1500:],
                    }
                )
            abuse = abusive_bodies(url, tokens["operator"])
        finally:
            server.terminate()
            server.wait(20)
        tracebacks = (out / "server.log").read_text(errors="replace").count("Traceback")
    table = Table(title=f"schemathesis against lastmile serve, {args.examples} examples per operation")
    for col in ("token role", "cases", "passed", "exit", "wall s"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            r["role"], str(r["generated"]), str(r["passed"]), str(r["exit_code"]), f"{r['wall_s']:.0f}"
        )
    console = Console(width=120)
    console.print(table)
    ok = all(r["exit_code"] == 0 and r["generated"] == r["passed"] for r in rows) and tracebacks == 0
    ok = ok and not abuse["server_errors"]
    console.print(f"abusive bodies to every operation with a body: {abuse['statuses']}")
    for line in abuse["server_errors"]:
        console.print(f"  5xx: {line}")
    console.print(f"server tracebacks: {tracebacks}; no server errors: {ok}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps({"rows": rows, "abuse": abuse, "server_tracebacks": tracebacks, "ok": ok}, indent=2) + "\n"
    )
    console.print(f"wrote {args.json}")
    if not ok:
        for r in rows:
            console.print(r["tail"])
        sys.exit(1)


if __name__ == "__main__":
    main()
