"""A crash, SIGTERM or SIGKILL of the recording process still leaves readable MCAP with the last 30 s."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
from pathlib import Path

from mcap.reader import make_reader

from lastmile.recorder.replay import read_recording
from tests.recorder.stream import TICK_US

CHILD = Path(__file__).with_name("crash_child.py")
WINDOW_US = 30_000_000


def _start(mode: str, out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(CHILD), mode, str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _check_last_30_s(path: Path, trigger: str) -> int:
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        start_us = summary.statistics.message_start_time // 1000
        end_us = summary.statistics.message_end_time // 1000
        events = [dict(m.metadata) for m in reader.iter_metadata() if m.name == "black_box_event"]
    rec = read_recording(path)
    last_us = rec.messages[-1].log_time_us
    assert rec.messages[0].log_time_us == last_us - WINDOW_US + TICK_US
    assert start_us == rec.messages[0].log_time_us and end_us >= last_us
    assert events and events[0]["trigger"] == trigger
    return last_us


def test_unhandled_exception_in_the_loop_leaves_a_valid_mcap_with_the_last_30_s(tmp_path: Path) -> None:
    proc = _start("raise", tmp_path)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1 and "planner blew up mid-run" in err
    (path,) = tmp_path.glob("blackbox_crash_*.mcap")
    last = _check_last_30_s(path, "crash")
    assert last == 39_990_000
    assert not list(tmp_path.glob("*.part"))


def test_sigterm_leaves_a_valid_mcap_with_the_last_30_s(tmp_path: Path) -> None:
    proc = _start("sigterm", tmp_path)
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM
    (path,) = tmp_path.glob("blackbox_sigterm_*.mcap")
    assert _check_last_30_s(path, "sigterm") >= 39_990_000


def test_sigkill_leaves_finished_spool_chunks_readable(tmp_path: Path) -> None:
    proc = _start("sigkill", tmp_path)
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "ready"
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    chunks = sorted((tmp_path / "spool").glob("chunk_*.mcap"))
    assert len(chunks) >= 6
    for chunk in chunks:
        read_recording(chunk)  # every finished chunk is a complete MCAP file
    rec = read_recording(tmp_path / "spool")
    first, last = rec.span_us
    # Finished chunks reach at least to the 35 s boundary flushed before "ready" and cover >= 25 s.
    assert last >= 35_000_000 - TICK_US and last - first >= 25_000_000
    times = [m.log_time_us for m in rec.messages if m.topic == "/stack/command"]
    assert all(b - a == TICK_US for a, b in itertools.pairwise(times))  # no gaps between chunks
