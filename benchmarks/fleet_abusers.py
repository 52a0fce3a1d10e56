"""Abusive clients of the dispatch server, run as their own process by ``fleet_load.py`` (so their CPU
is not the well-behaved client's event loop): 20 MB bodies with a Content-Length, 20 MB chunked
bodies, bodies that trickle in a byte at a time, NaN / Infinity / 1e309 numbers, and one rider token
flooding ride requests over several connections.

The NaN sender and the flood go as fast as their connections allow. The 20 MB senders start a new
body every ``BIG_EVERY_S`` (each, 40 MB/s of loopback traffic together): back to back they would be a
bandwidth flood of ~600 MB/s, which saturates these two cores' memory copies whatever the server does
and is a network's job to stop; what is tested here is that the server neither parses nor buffers them.

Each abuser holds a rider token of its own (flood, numbers, big, slow), so each meets the per-token
rate limit on its own: the flood and the NaN sender soon get 429 before their bodies are read.

Run by fleet_load.py: python benchmarks/fleet_abusers.py URL FLOOD,NUMBERS,BIG,SLOW SECONDS OUT.json
Writes, per abuser, the count of each HTTP status and of connections the server closed early.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from collections import Counter
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import aiohttp

BIG_BYTES = 20_000_000
BIG_EVERY_S = 1.0
SLOW_CONNECTIONS = 16
FLOOD_CONNECTIONS = 4
BAD_NUMBERS = (b"NaN", b"Infinity", b"-Infinity", b"1e309", b"9" * 400)


def _big_body() -> bytes:
    junk = b"0," * (BIG_BYTES // 2 - 1) + b"0"
    return b'{"origin": "S1", "destination": "S2", "junk": [' + junk + b"]}"


class Tally:
    def __init__(self) -> None:
        self.by_abuser: dict[str, Counter[str]] = {}

    def add(self, abuser: str, outcome: str) -> None:
        self.by_abuser.setdefault(abuser, Counter())[outcome] += 1


async def _post(http: aiohttp.ClientSession, tally: Tally, abuser: str, **kw: Any) -> None:
    try:
        async with http.post("/api/rides", **kw) as res:
            await res.read()
            tally.add(abuser, str(res.status))
    except (aiohttp.ClientError, ConnectionError):
        tally.add(abuser, "closed_early")


def _json_auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}", "Content-Type": "application/json"}


async def big_with_length(http: aiohttp.ClientSession, tally: Tally, t_end: float, token: str) -> None:
    body = _big_body()
    while time.perf_counter() < t_end:
        due = time.perf_counter() + BIG_EVERY_S
        await _post(http, tally, "20MB_content_length", data=body, headers=_json_auth(token))
        await asyncio.sleep(max(0.0, due - time.perf_counter()))


async def big_chunked(http: aiohttp.ClientSession, tally: Tally, t_end: float, token: str) -> None:
    body = _big_body()

    async def stream() -> AsyncIterator[bytes]:
        for k in range(0, len(body), 65_536):
            yield body[k : k + 65_536]

    while time.perf_counter() < t_end:
        due = time.perf_counter() + BIG_EVERY_S
        await _post(http, tally, "20MB_chunked", data=stream(), headers=_json_auth(token))
        await asyncio.sleep(max(0.0, due - time.perf_counter()))


async def slow_body(url: str, token: str, tally: Tally, t_end: float) -> None:
    """Headers promise 1,000 bytes; the body comes one byte every 0.5 s (a slowloris body)."""
    parts = urlsplit(url)
    while time.perf_counter() < t_end:
        try:
            reader, writer = await asyncio.open_connection(parts.hostname, parts.port)
            writer.write(
                f"POST /api/rides HTTP/1.1\r\nHost: {parts.netloc}\r\nAuthorization: Bearer {token}\r\n"
                f"Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n".encode()
            )
            await writer.drain()
            answered = asyncio.create_task(reader.readline())
            while not answered.done() and time.perf_counter() < t_end + 15:
                writer.write(b" ")
                await writer.drain()
                await asyncio.wait([answered], timeout=0.5)
            status = (await answered).split(b" ")[1].decode() if answered.done() else "no_answer"
            tally.add("slow_body", status)
            writer.close()
        except (ConnectionError, IndexError):
            tally.add("slow_body", "closed_early")


async def bad_numbers(http: aiohttp.ClientSession, tally: Tally, t_end: float, token: str) -> None:
    k = 0
    while time.perf_counter() < t_end:
        raw = b'{"origin": "S1", "destination": "S2", "seats": ' + BAD_NUMBERS[k % len(BAD_NUMBERS)] + b"}"
        await _post(http, tally, "nan_inf_1e309", data=raw, headers=_json_auth(token))
        k += 1


async def flood(http: aiohttp.ClientSession, tally: Tally, t_end: float, token: str, prefix: str) -> None:
    """One rider token, back to back: valid ride requests (each with its own client_ref)."""
    k = 0
    while time.perf_counter() < t_end:
        body = {"origin": "S1", "destination": "S3", "client_ref": f"{prefix}{k}"}
        k += 1
        await _post(http, tally, "flood_one_rider", json=body, headers=_json_auth(token))


async def run(url: str, tokens: dict[str, str], seconds: float) -> dict[str, Any]:
    tally = Tally()
    t_end = time.perf_counter() + seconds
    conn = aiohttp.TCPConnector(limit=0)
    timeout = aiohttp.ClientTimeout(total=60)
    async with aiohttp.ClientSession(base_url=url, connector=conn, timeout=timeout) as http:
        tasks = [
            big_with_length(http, tally, t_end, tokens["big"]),
            big_chunked(http, tally, t_end, tokens["big"]),
            bad_numbers(http, tally, t_end, tokens["numbers"]),
            *(slow_body(url, tokens["slow"], tally, t_end) for _ in range(SLOW_CONNECTIONS)),
        ]
        # Flood requests carry distinct client_refs so fleet_load can count them in the database.
        tasks += [flood(http, tally, t_end, tokens["flood"], f"flood-{n}-") for n in range(FLOOD_CONNECTIONS)]
        await asyncio.gather(*tasks)
    out: dict[str, Any] = {k: dict(v) for k, v in tally.by_abuser.items()}
    return out


def main() -> None:
    url, seconds, out = sys.argv[1], float(sys.argv[3]), Path(sys.argv[4])
    tokens = dict(zip(("flood", "numbers", "big", "slow"), sys.argv[2].split(","), strict=True))
    tally = asyncio.run(run(url, tokens, seconds))
    out.write_text(json.dumps({"tally": tally, "cpu_s": time.process_time()}, indent=2) + "\n")


if __name__ == "__main__":
    main()
