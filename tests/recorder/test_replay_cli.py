"""``lastmile replay``: a summary table of a recording, PNG rendering, one clear line for a bad file."""

from __future__ import annotations

from pathlib import Path

from mcap.reader import make_reader
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.recorder.black_box import BlackBox, BlackBoxConfig
from tests.recorder.stream import record_ticks


def _recording(tmp_path: Path) -> Path:
    bb = BlackBox(BlackBoxConfig(out_dir=tmp_path, window_us=2_000_000))
    last = max(record_ticks(bb, 0, 300, lidar_points=50))
    future = bb.trigger("emergency_stop", last, "goose on the road")
    bb.close()  # the last tick: close writes the dump still merging
    return future.result(timeout=60)


def test_replay_prints_channels_counts_span_and_events(tmp_path: Path) -> None:
    path = _recording(tmp_path)
    result = CliRunner().invoke(app, ["replay", str(path), "--render", str(tmp_path / "png"), "--fps", "2"])
    assert result.exit_code == 0, result.output
    assert "/stack/command" in result.output and "foxglove.PointCloud" in result.output
    assert "emergency_stop at 2.99 s: goose on the road" in result.output
    assert "200 messages" not in result.output  # the count is the whole window, not one channel
    assert len(list((tmp_path / "png").glob("frame_*.png"))) == 4  # 1.0 .. 2.99 s at 2 fps


def test_replay_of_a_bad_file_is_one_line_and_a_nonzero_exit(tmp_path: Path) -> None:
    bad = tmp_path / "notes.txt"
    bad.write_text("hello")
    result = CliRunner().invoke(app, ["replay", str(bad)])
    assert result.exit_code == 2
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("lastmile replay: expected a readable MCAP file")


def test_the_operators_summary_and_sound_are_attached_from_the_command_line(tmp_path: Path) -> None:
    path = _recording(tmp_path)
    wav = tmp_path / "summary.wav"
    wav.write_bytes(b"RIFF\x24\x00\x00\x00WAVEfmt ")
    result = CliRunner().invoke(
        app, ["replay", str(path), "--summary", "Goose stepped out at the crossing.", "--audio", str(wav)]
    )
    assert result.exit_code == 0 and "operator summary: Goose stepped out at the crossing." in result.output
    with open(path, "rb") as fh:  # the stock reader sees both attachments
        attachments = {a.name: (a.media_type, a.data) for a in make_reader(fh).iter_attachments()}
    assert attachments == {
        "operator_summary.txt": ("text/plain; charset=utf-8", b"Goose stepped out at the crossing."),
        "operator_summary": ("audio/wav", wav.read_bytes()),
    }
    bad = CliRunner().invoke(app, ["replay", str(path), "--summary", "x", "--audio", str(tmp_path / "a.txt")])
    lines = [ln for ln in bad.output.splitlines() if ln.strip()]
    assert bad.exit_code == 2 and len(lines) == 1 and "--audio: expected a .wav, .mp3" in lines[0]
