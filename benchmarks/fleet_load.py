"""Dispatch server under load on loopback: ride requests per second, latency, nothing lost or duplicated.

Run: python benchmarks/fleet_load.py [--rate 500] [--seconds 60] [--json out.json]

The server runs as its own process (uvicorn with uvloop/httptools, SQLite in WAL mode, group commit);
this process is the client: asyncio + aiohttp (httpx costs ~4.6 ms of client CPU per request here,
which alone would cap the load near 200/s on these cores), open loop (request i is due at
t0 + i / rate, and its latency counts from when it was due, so a stalled server cannot hide its
queueing). Four shuttles are
in service, so every request runs the insertion heuristic. Afterwards the database is read back: every
request sent must be there exactly once (each carries a unique ``client_ref``).

Baseline, same run: the same server with one commit per request (``commit_batch=1``, the design one
writes first), measured as the highest rate each sustains in a short closed-loop burst. Target of
issue #6: >= 500 requests/s sustained for 60 s, none lost or duplicated, p99 printed.

Riders: each request carries one of ``--riders`` rider tokens in turn (every token stays far under its
rate limit of 20/s), as a campus of riders would.

Abuse (issue #21): well-behaved riders at ``--abuse-rate`` for ``--abuse-seconds``, first alone and
then while ``fleet_abusers.py`` (its own process) sends 20 MB bodies (with a Content-Length, and
chunked), bodies that trickle in a byte at a time, NaN / Infinity / 1e309 numbers, and a flood of
ride requests from one rider token over four connections. Target: no 5xx and no traceback anywhere,
no ride lost or duplicated (the flood's accepted rides included), and the well-behaved riders' p99
under 100 ms while it lasts; the ratio is their p99 with the abusers over their p99 alone. Control:
the same abusers aimed at a second, identical server while the riders use the first, so the machine
is as busy but the riders' server is not attacked: the gap between the two is what the attack itself
costs the riders, the rest is the two cores' contention.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import aiohttp
import httpx
import sqlalchemy as sa
from rich.console import Console
from rich.table import Table

TARGET_RPS = 500.0
ABUSE_P99_TARGET_MS = 100.0
STOPS = ("S1", "S2", "S3", "S4")

SERVER = """
import sys, uvicorn
from pathlib import Path
from lastmile.fleet.server import ServerConfig, create_app
out = Path(sys.argv[1])
cfg = ServerConfig(db_url=f"sqlite:///{out / 'fleet.db'}", out_dir=out, runs_dir=out / "runs",
                   commit_batch=int(sys.argv[3]), timetable_lead_s=0.0)
uvicorn.run(create_app(cfg), host="127.0.0.1", port=int(sys.argv[2]), log_level="warning", access_log=False)
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    def __init__(self, out: Path, commit_batch: int, riders: int) -> None:
        self.out = out
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        out.mkdir(parents=True, exist_ok=True)
        self.proc = subprocess.Popen(
            [sys.executable, "-c", SERVER, str(out), str(self.port), str(commit_batch)],
            stdout=open(out / "server.log", "wb"),  # noqa: SIM115  lives as long as the process
            stderr=subprocess.STDOUT,
        )
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if httpx.get(self.url + "/openapi.json", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.1)
        else:
            raise RuntimeError("server did not start: " + (out / "server.log").read_text()[-2000:])
        self.tokens = json.loads((out / "tokens.json").read_text())
        op = {"Authorization": f"Bearer {self.tokens['operator']}"}
        for k in range(4):
            httpx.post(self.url + "/api/vehicles", json={"id": f"bench-{k}"}, headers=op).raise_for_status()
            httpx.post(
                self.url + f"/api/vehicles/bench-{k}/command", json={"command": "start_service"}, headers=op
            ).raise_for_status()
        self.riders = [self.issue(op, "rider", f"rider-{k}") for k in range(riders)]
        # One token per abuser (flood, numbers, big, slow): each meets its own rate limit.
        self.abusers = [self.issue(op, "rider", f"abuser-{k}") for k in ("flood", "numbers", "big", "slow")]

    def issue(self, op: dict[str, str], role: str, subject: str) -> str:
        res = httpx.post(self.url + "/api/tokens", json={"role": role, "subject": subject}, headers=op)
        res.raise_for_status()
        return str(res.json()["token"])

    def cpu_s(self) -> float:
        """CPU seconds (user + system) the server process has used so far."""
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def tracebacks(self) -> int:
        return (self.out / "server.log").read_text(errors="replace").count("Traceback")

    def rows(self, prefix: str) -> tuple[int, int]:
        """(rows whose client_ref starts with prefix, distinct such client_refs) in the database."""
        engine = sa.create_engine(f"sqlite:///{self.out / 'fleet.db'}")
        with engine.connect() as conn:
            n, distinct = conn.execute(
                sa.text(
                    "SELECT count(*), count(DISTINCT client_ref) FROM ride_requests WHERE client_ref LIKE :p"
                ),
                {"p": prefix + "%"},
            ).one()
        engine.dispose()
        return int(n), int(distinct)

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(20)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def _body(i: int, prefix: str) -> dict[str, Any]:
    o = STOPS[i % 4]
    d = STOPS[(i + 1 + (i // 4) % 3) % 4]
    return {"origin": o, "destination": d, "seats": 1 + i % 2, "client_ref": f"{prefix}{i}"}


def _by_second(timeline: list[tuple[float, float]]) -> list[float]:
    """Median latency (ms) of the requests due in each second of the run."""
    buckets: dict[int, list[float]] = {}
    for due_s, lat_s in timeline:
        buckets.setdefault(int(due_s), []).append(lat_s)
    return [1e3 * sorted(v)[len(v) // 2] for _, v in sorted(buckets.items())]


def _auth(tokens: list[str], i: int) -> dict[str, str]:
    return {"Authorization": f"Bearer {tokens[i % len(tokens)]}"}


async def open_loop(
    url: str, tokens: list[str], rate: float, seconds: float, prefix: str, conns: int
) -> dict[str, Any]:
    """Send ``rate * seconds`` requests on schedule; latency from each request's due time."""
    n = int(rate * seconds)
    lat: list[float] = []
    timeline: list[tuple[float, float]] = []
    statuses: dict[int, int] = {}
    errors = 0
    connector = aiohttp.TCPConnector(limit=conns)
    async with aiohttp.ClientSession(base_url=url, connector=connector) as http:
        t0 = time.perf_counter() + 0.2

        async def one(i: int) -> None:
            nonlocal errors
            due = t0 + i / rate
            try:
                async with http.post("/api/rides", json=_body(i, prefix), headers=_auth(tokens, i)) as res:
                    await res.read()
                    statuses[res.status] = statuses.get(res.status, 0) + 1
            except aiohttp.ClientError:
                errors += 1
                return
            lat.append(time.perf_counter() - due)
            timeline.append((due - t0, time.perf_counter() - due))

        tasks = []
        for i in range(n):
            delay = t0 + i / rate - time.perf_counter()
            if delay > 0:
                await asyncio.sleep(delay)
            tasks.append(asyncio.create_task(one(i)))
        await asyncio.gather(*tasks)
        wall = time.perf_counter() - t0
    lat.sort()
    last_due = (n - 1) / rate
    return {
        "sent": n,
        # How long after the last request was due the last answer came: under a second means the
        # server kept up with the offered rate for the whole run instead of building a queue.
        "backlog_at_end_s": wall - last_due,
        "statuses": statuses,
        "transport_errors": errors,
        "wall_s": wall,
        "achieved_rps": statuses.get(201, 0) / wall,
        "p50_ms": 1e3 * lat[len(lat) // 2] if lat else None,
        "p99_ms": 1e3 * lat[int(len(lat) * 0.99)] if lat else None,
        "max_ms": 1e3 * lat[-1] if lat else None,
        "p50_ms_by_second": _by_second(timeline),
    }


async def closed_loop(url: str, tokens: list[str], seconds: float, prefix: str, conns: int) -> dict[str, Any]:
    """``conns`` clients each sending back to back: the highest rate the server sustains."""
    done = 0
    lat: list[float] = []
    connector = aiohttp.TCPConnector(limit=conns)
    async with aiohttp.ClientSession(base_url=url, connector=connector) as http:
        t_end = time.perf_counter() + seconds
        counter = iter(range(10**9))

        async def worker() -> None:
            nonlocal done
            while time.perf_counter() < t_end:
                t = time.perf_counter()
                i = next(counter)
                async with http.post("/api/rides", json=_body(i, prefix), headers=_auth(tokens, i)) as res:
                    await res.read()
                    if res.status == 201:
                        done += 1
                        lat.append(time.perf_counter() - t)

        t0 = time.perf_counter()
        await asyncio.gather(*(worker() for _ in range(conns)))
        wall = time.perf_counter() - t0
    lat.sort()
    return {
        "created": done,
        "wall_s": wall,
        "rps": done / wall,
        "p50_ms": 1e3 * lat[len(lat) // 2] if lat else None,
        "p99_ms": 1e3 * lat[int(len(lat) * 0.99)] if lat else None,
    }


def _start_abusers(target: Server, seconds: float, out: Path) -> subprocess.Popen[bytes]:
    script = Path(__file__).with_name("fleet_abusers.py")
    return subprocess.Popen(
        [sys.executable, str(script), target.url, ",".join(target.abusers), str(seconds + 3.0), str(out)]
    )


def control_phase(
    server: Server, decoy: Server, rate: float, seconds: float, conns: int, tmp: Path
) -> dict[str, Any]:
    """Control: the same abusers aimed at a second, identical server while the riders use the first.
    The machine is as busy (abusers' process, a server answering them), the riders' server is not
    attacked: what the riders' p99 rises by here is CPU contention, not the server's handling."""
    abusers = _start_abusers(decoy, seconds, tmp / "abusers-control.json")
    time.sleep(1.5)
    run = asyncio.run(open_loop(server.url, server.riders, rate, seconds, "calm-control-", conns))
    abusers.wait(120)
    rows, distinct = server.rows("calm-control-")
    return run | {"db_rows": rows, "lost": run["sent"] - rows, "duplicated": rows - distinct}


def abuse_phase(server: Server, rate: float, seconds: float, conns: int, tmp: Path) -> dict[str, Any]:
    """Well-behaved riders alone, then the same load while the abusers run (their own process)."""
    cpu0 = server.cpu_s()
    calm = asyncio.run(open_loop(server.url, server.riders, rate, seconds, "calm-alone-", conns))
    calm["server_cpu_s"] = server.cpu_s() - cpu0
    out = tmp / "abusers.json"
    abusers = _start_abusers(server, seconds, out)
    time.sleep(1.5)  # the abusers are in full swing before the measured window opens
    cpu0 = server.cpu_s()
    attacked = asyncio.run(open_loop(server.url, server.riders, rate, seconds, "calm-abused-", conns))
    attacked["server_cpu_s"] = server.cpu_s() - cpu0
    abusers.wait(120)
    report = json.loads(out.read_text())
    tally: dict[str, dict[str, int]] = report["tally"]
    for run, prefix in ((calm, "calm-alone-"), (attacked, "calm-abused-")):
        rows, distinct = server.rows(prefix)
        run |= {"db_rows": rows, "lost": run["sent"] - rows, "duplicated": rows - distinct}
    flood_rows, flood_distinct = server.rows("flood-")
    flood_created = tally.get("flood_one_rider", {}).get("201", 0)
    server_errors = sum(
        n for run in (calm, attacked) for code, n in run["statuses"].items() if int(code) >= 500
    ) + sum(
        n for counts in tally.values() for code, n in counts.items() if code.isdigit() and int(code) >= 500
    )
    return {
        "rate": rate,
        "seconds": seconds,
        "alone": calm,
        "with_abusers": attacked,
        "abusers": tally,
        "abusers_cpu_s": report["cpu_s"],
        "flood_created": flood_created,
        "flood_db_rows": flood_rows,
        "flood_lost": flood_created - flood_rows,
        "flood_duplicated": flood_rows - flood_distinct,
        "server_errors": server_errors,
        "server_tracebacks": server.tracebacks(),
        "p99_ratio_with_vs_without": attacked["p99_ms"] / calm["p99_ms"],
    }


def abuse_target_met(a: dict[str, Any]) -> bool:
    runs = (a["alone"], a["with_abusers"])
    return bool(
        a["server_errors"] == 0
        and a["server_tracebacks"] == 0
        and all(r["lost"] == 0 and r["duplicated"] == 0 and r["transport_errors"] == 0 for r in runs)
        and all(r["statuses"].get(201, 0) == r["sent"] for r in runs)
        and a["flood_lost"] == 0
        and a["flood_duplicated"] == 0
        and a["with_abusers"]["p99_ms"] < ABUSE_P99_TARGET_MS
    )


def print_abuse(console: Console, a: dict[str, Any]) -> None:
    table = Table(
        title=f"well-behaved riders at {a['rate']:g}/s for {a['seconds']:g} s, alone and under abuse"
    )
    cols = (
        "run",
        "requests",
        "201",
        "p50 ms",
        "p99 ms",
        "max ms",
        "lost",
        "dup",
        "server CPU s",
        "p99 ratio",
    )
    for col in cols:
        table.add_column(col, justify="right")
    runs = [("alone", a["alone"]), ("with abusers", a["with_abusers"])]
    runs.append(("control: abusers hit another server", a["control_abusers_elsewhere"]))
    for name, r in runs:
        table.add_row(
            name,
            str(r["sent"]),
            str(r["statuses"].get(201, 0)),
            f"{r['p50_ms']:.1f}",
            f"{r['p99_ms']:.1f}",
            f"{r['max_ms']:.1f}",
            str(r["lost"]),
            str(r["duplicated"]),
            f"{r['server_cpu_s']:.1f}" if "server_cpu_s" in r else "",
            f"{r['p99_ms'] / a['alone']['p99_ms']:.2f}x",
        )
    console.print(table)
    abuse = Table(title="what the abusers got")
    abuse.add_column("abuser")
    abuse.add_column("outcomes (HTTP status or connection closed early: count)")
    for name, counts in sorted(a["abusers"].items()):
        abuse.add_row(name, ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
    console.print(abuse)
    console.print(f"abusers' own CPU: {a['abusers_cpu_s']:.1f} s (their process, on the same two cores)")
    console.print(
        f"flood: {a['flood_created']} accepted, {a['flood_db_rows']} in the database "
        f"(lost {a['flood_lost']}, duplicated {a['flood_duplicated']}); "
        f"server 5xx {a['server_errors']}, tracebacks {a['server_tracebacks']}; "
        f"target met (no 5xx, nothing lost or duplicated, p99 < "
        f"{ABUSE_P99_TARGET_MS:g} ms): {a['target_met']}"
    )


def capacity_phases(args: argparse.Namespace, tmp: Path, result: dict[str, Any]) -> None:
    for name, batch in (("group_commit", 512), ("commit_per_request", 1)):
        server = Server(tmp / name, batch, args.riders)
        try:
            burst = asyncio.run(
                closed_loop(server.url, server.riders, args.burst_seconds, f"{name}-burst-", args.conns)
            )
            entry: dict[str, Any] = {"capacity": burst}
            rows, distinct = server.rows(f"{name}-burst-")
            entry["capacity"]["db_rows"] = rows
            if name == "group_commit":
                run = asyncio.run(
                    open_loop(server.url, server.riders, args.rate, args.seconds, "sustain-", args.conns)
                )
                rows, distinct = server.rows("sustain-")
                run |= {"db_rows": rows, "db_distinct": distinct}
                run["lost"] = run["sent"] - rows
                run["duplicated"] = rows - distinct
                entry["sustained"] = run
            result[name] = entry
        finally:
            server.stop()


def print_capacity(console: Console, args: argparse.Namespace, result: dict[str, Any]) -> None:
    s = result["group_commit"]["sustained"]
    cap, base = result["group_commit"]["capacity"], result["commit_per_request"]["capacity"]
    result["capacity_ratio_vs_commit_per_request"] = cap["rps"] / base["rps"]
    ok_rate = s["statuses"].get(201, 0) == s["sent"] and s["backlog_at_end_s"] < 1.0
    result["target_met"] = bool(
        ok_rate and s["lost"] == 0 and s["duplicated"] == 0 and args.seconds >= 60 and args.rate >= TARGET_RPS
    )
    table = Table(
        title=f"dispatch server on loopback ({os.cpu_count()} cores shared, client in this process)"
    )
    for col in ("run", "requests", "req/s done", "p50 ms", "p99 ms", "lost", "dup", "capacity ratio"):
        table.add_column(col, justify="right")
    table.add_row(
        f"sustained {args.rate:g}/s x {args.seconds:g} s",
        str(s["sent"]),
        f"{s['achieved_rps']:.0f}",
        f"{s['p50_ms']:.1f}",
        f"{s['p99_ms']:.1f}",
        str(s["lost"]),
        str(s["duplicated"]),
        "",
    )
    table.add_row(
        f"capacity, group commit ({args.conns} clients)",
        str(cap["created"]),
        f"{cap['rps']:.0f}",
        f"{cap['p50_ms']:.1f}",
        f"{cap['p99_ms']:.1f}",
        str(cap["created"] - cap["db_rows"]),
        "",
        f"{result['capacity_ratio_vs_commit_per_request']:.2f}x",
    )
    table.add_row(
        "capacity, commit per request (baseline)",
        str(base["created"]),
        f"{base['rps']:.0f}",
        f"{base['p50_ms']:.1f}",
        f"{base['p99_ms']:.1f}",
        str(base["created"] - base["db_rows"]),
        "",
        "1.00x",
    )
    console.print(table)
    console.print(
        f"sustained run: statuses {s['statuses']}, transport errors {s['transport_errors']}, last answer "
        f"{s['backlog_at_end_s']:.2f} s after the last request was due; target met: {result['target_met']}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rate", type=float, default=TARGET_RPS, help="requests per second to sustain")
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--burst-seconds", type=float, default=10.0, help="closed-loop capacity bursts")
    parser.add_argument("--conns", type=int, default=32)
    parser.add_argument("--riders", type=int, default=100, help="rider tokens the load is spread over")
    parser.add_argument("--abuse-rate", type=float, default=100.0, help="well-behaved requests/s under abuse")
    parser.add_argument("--abuse-seconds", type=float, default=30.0)
    parser.add_argument("--only-abuse", action="store_true", help="skip the capacity and sustained runs")
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/fleet_load.json"))
    args = parser.parse_args()
    console = Console(width=150)
    load = os.getloadavg()
    result: dict[str, Any] = {
        "cpus": os.cpu_count(),
        "load_average_at_start": load,
        "rate": args.rate,
        "seconds": args.seconds,
    }
    console.print(
        f"{os.cpu_count()} cores, load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at start"
    )
    with tempfile.TemporaryDirectory(prefix="fleet-load-") as tmp:
        if not args.only_abuse:
            capacity_phases(args, Path(tmp), result)
        server = Server(Path(tmp) / "abuse", 512, args.riders)
        decoy = Server(Path(tmp) / "decoy", 512, 1)
        try:
            result["abuse"] = abuse_phase(server, args.abuse_rate, args.abuse_seconds, args.conns, Path(tmp))
            result["abuse"]["control_abusers_elsewhere"] = control_phase(
                server, decoy, args.abuse_rate, args.abuse_seconds, args.conns, Path(tmp)
            )
        finally:
            server.stop()
            decoy.stop()
    result["abuse"]["target_met"] = abuse_target_met(result["abuse"])
    result["load_average_at_end"] = os.getloadavg()
    if not args.only_abuse:
        print_capacity(console, args, result)
    print_abuse(console, result["abuse"])
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    console.print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
