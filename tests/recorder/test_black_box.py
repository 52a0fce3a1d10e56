"""Black box: exact 30 s window, background dumps with Foxglove schemas, summary, replay round trip."""

from __future__ import annotations

import dataclasses
import itertools
import json
from collections import deque
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from foxglove import messages as fm
from mcap.reader import make_reader
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TrackedObjects
from lastmile.core.sensor_frames import CameraDetections, LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand, LocalizationEstimate, TurnSignal
from lastmile.recorder import record_schemas
from lastmile.recorder.black_box import BlackBox, BlackBoxConfig
from lastmile.recorder.foxglove_views import ViewBuilder, planar_matrix
from lastmile.recorder.mcap_codec import RecordingError, encode_message
from lastmile.recorder.replay import read_recording
from lastmile.recorder.replay_render import render_png_sequence
from tests.recorder.stream import TICK_US, record_ticks

WINDOW_US = 30_000_000


def _cmd(now: int) -> ActuatorCommand:
    return ActuatorCommand(stamp=Stamp(now), accel_mps2=0.0, steer_front_rad=0.0, steer_rear_rad=0.0)


def test_window_keeps_exactly_the_last_30_s(tmp_path: Path) -> None:
    bb = BlackBox(BlackBoxConfig(out_dir=tmp_path))
    for tick in range(6000):  # 60 s at 100 Hz
        bb.record(tick * TICK_US, "/stack/command", _cmd(tick * TICK_US))
    window = bb.window()
    newest = 5999 * TICK_US
    assert window[-1][0] == newest
    assert window[0][0] == newest - WINDOW_US + TICK_US  # (newest - 30 s, newest]
    assert len(window) == 3000
    bb.close()


def test_a_dump_interrupting_a_record_call_never_holds_more_than_the_window(tmp_path: Path) -> None:
    # A SIGTERM handler runs between any two bytecodes of the loop, so it can dump while ``record`` is
    # half done. The window as it stands right after the append (the only mutation a dump could see
    # before the call returns) must already span less than 30 s.
    bb = BlackBox(BlackBoxConfig(out_dir=tmp_path))
    spans: list[int] = []

    class Watched(deque):
        def append(self, entry: tuple) -> None:
            super().append(entry)
            spans.append(self[-1][0] - self[0][0])

    bb._window = Watched()
    for tick in range(4000):
        bb.record(tick * TICK_US, "/stack/command", _cmd(tick * TICK_US))
    assert len(spans) == 4000 and max(spans) == WINDOW_US - TICK_US
    bb.close()


@pytest.fixture(scope="module")
def dumped(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, BlackBox, list]:
    out = tmp_path_factory.mktemp("bb")
    mounts = {"lidar_top": planar_matrix(1.2, 0.0, 0.0, 1.9), "radar_front": planar_matrix(3.75, 0.0, 0.0)}
    # merge_us=0: the file is written at the trigger, so the ticks after it cannot leak in.
    bb = BlackBox(BlackBoxConfig(out_dir=out, sensor_mounts=mounts, merge_us=0))
    last = max(record_ticks(bb, 0, 3500))  # 35 s of ticks
    snapshot = list(bb.window())
    future = bb.trigger("takeover", last, "operator braked for a pedestrian")
    # More ticks while the file is written must not leak into it.
    for _ in record_ticks(bb, 3500, 50):
        pass
    path = future.result(timeout=60)
    bb.close()
    return path, bb, snapshot


def test_the_command_channel_carries_the_indicator_lights(tmp_path: Path) -> None:
    bb = BlackBox(BlackBoxConfig(out_dir=tmp_path, merge_us=0))
    signals = list(TurnSignal)
    for k, signal in enumerate(signals):
        bb.record(k * TICK_US, "/stack/command", dataclasses.replace(_cmd(k * TICK_US), turn_signal=signal))
    path = bb.trigger("takeover", (len(signals) - 1) * TICK_US, "test").result(timeout=60)
    bb.close()
    rec = read_recording(path)
    assert [m.message.turn_signal for m in rec.messages if m.topic == "/stack/command"] == signals


def test_trigger_writes_the_window_with_foxglove_schemas(dumped: tuple[Path, BlackBox, list]) -> None:
    path, _, snapshot = dumped
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        schemas = {s.name: s.encoding for s in summary.schemas.values()}
        channel_topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        stats = summary.statistics
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    for name in (
        "foxglove.PointCloud",
        "foxglove.PoseInFrame",
        "foxglove.FrameTransforms",
        "foxglove.SceneUpdate",
        "foxglove.Log",
    ):
        assert schemas[name] == "protobuf"
    assert channel_topics["/sensors/lidar/top"] == "foxglove.PointCloud"
    assert channel_topics["/viz/sensors/radar/front"] == "foxglove.PointCloud"
    assert channel_topics["/tf"] == "foxglove.FrameTransforms"
    assert channel_topics["/pose"] == "foxglove.PoseInFrame"
    assert channel_topics["/viz/tracking/tracks"] == "foxglove.SceneUpdate"
    assert channel_topics["/viz/planning/trajectory"] == "foxglove.SceneUpdate"
    assert stats.message_start_time == (34_990_000 - WINDOW_US + TICK_US) * 1000  # (newest - 30 s, newest]
    assert stats.message_end_time == 34_990_000 * 1000
    ev = meta["black_box_event"]
    assert ev["trigger"] == "takeover" and ev["reason"] == "operator braked for a pedestrian"
    assert ev["time_us"] == "34990000"
    rec = read_recording(path)
    assert len(rec.messages) == len(snapshot)


def test_replay_round_trips_every_message(dumped: tuple[Path, BlackBox, list]) -> None:
    path, _, snapshot = dumped
    rec = read_recording(path)
    assert [(m.log_time_us, m.topic) for m in rec.messages] == [(t, topic) for t, topic, _ in snapshot]
    for m, (_, _, original) in zip(rec.messages, snapshot, strict=True):
        assert type(m.message) is type(original)
        if isinstance(original, LidarSweep):
            assert m.message.stamp == original.stamp and m.message.sensor_id == original.sensor_id
            assert np.array_equal(m.message.points, original.points)
        else:
            assert encode_message(m.message) == encode_message(original)
    assert rec.events[0]["trigger"] == "takeover"
    ticks = list(rec.ticks())
    assert all(t1 > t0 for (t0, _), (t1, _) in itertools.pairwise(ticks))
    assert sum(len(f) for _, f in ticks) == sum(
        1 for _, topic, _ in snapshot if topic.startswith("/sensors/")
    )
    stamps = [int(f.stamp) for f in rec.frames_in_capture_order()]
    assert stamps == sorted(stamps)


def test_operator_summary_is_added_to_a_finished_dump(
    dumped: tuple[Path, BlackBox, list], tmp_path: Path
) -> None:
    src, _, _ = dumped
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(src.read_bytes())
    before = read_recording(copy)
    assert before.operator_summary is None
    BlackBox.add_operator_summary(
        copy, "Pedestrian stepped out behind the van.", audio=b"RIFF....WAVE", at_us=35_000_000
    )
    after = read_recording(copy)
    assert after.operator_summary == "Pedestrian stepped out behind the van."
    assert after.attachments == (
        ("operator_summary.txt", "text/plain; charset=utf-8", b"Pedestrian stepped out behind the van."),
        ("operator_summary", "audio/wav", b"RIFF....WAVE"),
    )
    assert len(after.messages) == len(before.messages) and after.events == before.events


def test_triggers_in_the_cooldown_merge_and_unknown_triggers_are_rejected(tmp_path: Path) -> None:
    bb = BlackBox(BlackBoxConfig(out_dir=tmp_path, window_us=1_000_000))
    bb.record(0, "/stack/command", _cmd(0))
    first = bb.trigger("collision", 0, "contact")
    assert bb.trigger("collision", 1_000_000, "contact again") is first
    with pytest.raises(ConfigError, match="'explosion'"):
        bb.trigger("explosion", 0, "")
    bb.close()
    assert len(list(tmp_path.glob("*.mcap"))) == 1


def test_replay_renders_a_png_sequence(dumped: tuple[Path, BlackBox, list], tmp_path: Path) -> None:
    rec = read_recording(dumped[0])
    paths = render_png_sequence(rec, tmp_path / "png", fps=2.0, max_frames=3)
    assert [p.name for p in paths] == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_file_that_is_not_mcap_is_one_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match=r"bad\.mcap"):
        read_recording(bad)
    with pytest.raises(RecordingError, match="no such file"):
        read_recording(tmp_path / "missing.mcap")


def test_every_channel_has_the_sdks_schema_or_a_documented_one_its_messages_validate_against(
    dumped: tuple[Path, BlackBox, list],
) -> None:
    decoders = DecoderFactory()
    seen: set[str] = set()
    validators: dict[int, jsonschema.protocols.Validator] = {}
    with open(dumped[0], "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            assert schema is not None
            if schema.name.startswith("foxglove."):
                sdk = getattr(fm, schema.name.removeprefix("foxglove.")).get_schema()
                assert (schema.encoding, schema.data) == (sdk.encoding, sdk.data), schema.name
                decoder = decoders.decoder_for(channel.message_encoding, schema)
                assert decoder is not None and decoder(message.data) is not None
            else:
                assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
                if schema.id not in validators:
                    doc = json.loads(schema.data)
                    assert doc["title"] == schema.name and doc["description"], schema.name
                    jsonschema.Draft202012Validator.check_schema(doc)
                    validators[schema.id] = jsonschema.Draft202012Validator(doc)
                validators[schema.id].validate(json.loads(message.data))
            seen.add(schema.name)
    assert {
        "foxglove.PointCloud",
        "foxglove.PoseInFrame",
        "foxglove.FrameTransforms",
        "foxglove.SceneUpdate",
        "foxglove.Log",
        "lastmile.ActuatorCommand",
        "lastmile.TrackedObjects",
        "lastmile.BlackBoxEvent",
    } <= seen


def test_a_documented_schema_names_each_field_with_its_type_and_description() -> None:
    doc = json.loads(record_schemas.schema_for(LocalizationEstimate))
    props = doc["properties"]
    assert props["valid"]["type"] == "boolean" and props["stamp"]["type"] == "integer"
    assert props["map_from_base"] == {"$ref": "#/$defs/SE2"} and "x_m" in doc["$defs"]["SE2"]["properties"]
    tracks = json.loads(record_schemas.schema_for(TrackedObjects))
    assert "track ids" in tracks["properties"]["ids"]["description"]
    assert tracks["properties"]["table"]["properties"]["$array"]["contentEncoding"] == "base64"
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"$type": "LocalizationEstimate", "valid": "yes"}, doc)


def test_triggers_close_in_time_share_one_file_with_all_their_events(tmp_path: Path) -> None:
    bb = BlackBox(BlackBoxConfig(out_dir=tmp_path, window_us=3_000_000, merge_us=1_000_000))
    ticks = record_ticks(bb, 0, 220, lidar_points=20)
    for _ in range(220):
        now = next(ticks)
        if now == 1_000_000:
            takeover = bb.trigger("takeover", now, "operator took over")
            mrm = bb.trigger("mrm", now, "front radar silent")  # the same tick
        if now == 1_090_000:
            estop = bb.trigger("emergency_stop", now, "operator e-stop")  # 90 ms later
    assert takeover is mrm is estop
    path = takeover.result(timeout=60)  # written once the merge time passed (the loop went on)
    late = bb.trigger("collision", 2_190_000, "contact")  # after the merge time: a new incident
    bb.close()
    assert late.result(timeout=60) != path
    rec = read_recording(path)
    assert [(e["trigger"], e["time_us"]) for e in rec.events] == [
        ("takeover", "1000000"),
        ("mrm", "1000000"),
        ("emergency_stop", "1090000"),
    ]
    assert rec.span_us == (0, 2_000_000)  # from window before the first trigger to the merge time after
    assert bb.dump_triggers[path] == ("takeover", "mrm", "emergency_stop")
    assert len(list(tmp_path.glob("*.mcap"))) == 2


def test_a_crash_dump_takes_the_events_of_a_dump_still_merging(tmp_path: Path) -> None:
    bb = BlackBox(BlackBoxConfig(out_dir=tmp_path, merge_us=2_000_000))
    last = max(record_ticks(bb, 0, 100, lidar_points=20))
    pending = bb.trigger("takeover", last - 50_000, "operator took over")
    crash = bb.dump("crash", "stack raised")
    assert pending.result(timeout=1) == crash
    assert [e["trigger"] for e in read_recording(crash).events] == ["takeover", "crash"]
    bb.close()
    assert list(tmp_path.glob("*.mcap")) == [crash]


def _stock_reader_count(data: bytes) -> int:
    """Messages the stock ``mcap`` stream reader yields before it stops on the damage."""
    import io

    from mcap import records
    from mcap.stream_reader import StreamReader

    n = 0
    try:
        for rec in StreamReader(io.BytesIO(data), record_size_limit=None).records:
            n += isinstance(rec, records.Message)
    except Exception:
        pass
    return n


def test_a_file_cut_short_is_read_as_far_as_it_goes_with_one_warning(
    dumped: tuple[Path, BlackBox, list], tmp_path: Path
) -> None:
    data = dumped[0].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 5])
    rec = read_recording(cut)
    stock = _stock_reader_count(cut.read_bytes())
    n = sum(c.count for c in rec.channels)
    assert 0 < n == stock < sum(c.count for c in read_recording(dumped[0]).channels)
    assert rec.warning is not None and "cut short" in rec.warning and f"{n} messages" in rec.warning
    assert rec.messages and all(m.log_time_us <= rec.span_us[1] for m in rec.messages)
    result = CliRunner().invoke(app, ["replay", str(cut)])
    assert result.exit_code == 0, result.output
    warnings = [ln for ln in result.output.splitlines() if "warning" in ln]
    assert len(warnings) == 1 and warnings[0].startswith("lastmile replay: warning: ")


def test_camera_boxes_become_image_annotations_with_class_and_score() -> None:
    boxes = np.array([[100, 50, 180, 200, int(ObjectClass.PEDESTRIAN), 0.9]], dtype=np.float32)
    det = CameraDetections(stamp=Stamp(2_000_000), camera_id="front", boxes=boxes)
    views = list(ViewBuilder(sensor_mounts={}).views(2_000_000, "/sensors/camera/front", det))
    assert [(t, type(m).__name__) for t, m in views] == [("/viz/sensors/camera/front", "ImageAnnotations")]
    schema = fm.ImageAnnotations.get_schema()
    record = Schema(id=1, name=schema.name, encoding=schema.encoding, data=schema.data)
    back = DecoderFactory().decoder_for("protobuf", record)(views[0][1].encode())  # type: ignore[misc]
    assert [(p.x, p.y) for p in back.points[0].points] == [(100, 50), (180, 50), (180, 200), (100, 200)]
    assert back.texts[0].text == "pedestrian 0.90"


def test_a_rendered_frames_title_names_the_indicators_when_on() -> None:
    from lastmile.recorder.replay_render import _title

    left = dataclasses.replace(_cmd(0), turn_signal=TurnSignal.LEFT)
    assert _title(None, left, 1_000_000) == "t = 1.00 s  indicators left"
    assert _title(None, _cmd(0), 1_000_000) == "t = 1.00 s"
