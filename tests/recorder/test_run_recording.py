"""A real run's black box, opened with the stock ``mcap`` reader: Foxglove's schemas or documented ones of
ours, a transform tree that places every frame, one file per incident, and a picture of it."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from foxglove import messages as fm
from matplotlib import image as mpimg
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.run_events import EventKind
from lastmile.recorder.replay import read_recording
from lastmile.recorder.replay_render import render_png
from lastmile.recorder.run_log import RunLog
from lastmile.runner.closed_loop import build_closed_loop, run_scenario, sensor_calibration
from lastmile.runner.loop_callbacks import sensor_frame_mounts
from lastmile.runner.replay_through_stack import replay_through_stack
from lastmile.runner.run_config import RunConfig
from lastmile.sim.scenario import RingCar, default_service
from tests.closed_loop.harness import RADAR

pytestmark = pytest.mark.closed_loop

FOXGLOVE_SCHEMAS = {
    f"foxglove.{name}"
    for name in dir(fm)
    if hasattr(getattr(fm, name), "get_schema") and getattr(fm, name).get_schema().name == f"foxglove.{name}"
}
"""Foxglove's published schema set, as the SDK ships it."""


@pytest.fixture(scope="module")
def estop_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, RunLog]:
    """8 s of the default service with cars around; the operator presses the e-stop at about 5 s."""
    scenario = dataclasses.replace(
        default_service(seed=0, minutes=8.0 / 60.0),
        name="estop_recording",
        ring_cars=(
            RingCar(direction="ccw", start_s_m=45.0, speed_mps=4.0),
            RingCar(direction="cw", start_s_m=60.0, speed_mps=4.0),
        ),
        estop_in_state="normal_driving",
        estop_min_speed_mps=2.0,
    )
    out = tmp_path_factory.mktemp("run") / "recordings"
    log = run_scenario(scenario, RADAR, black_box_dir=out)
    return out, log


def _recordings(estop_run: tuple[Path, RunLog]) -> list[Path]:
    return sorted(estop_run[0].glob("*.mcap"))


def test_a_takeover_and_an_estop_90_ms_apart_make_one_file_with_both_events(
    estop_run: tuple[Path, RunLog],
) -> None:
    _, log = estop_run
    files = _recordings(estop_run)
    assert len(files) == 1, files
    rec = read_recording(files[0])
    triggers = {ev["trigger"]: int(ev["time_us"]) for ev in rec.events}
    assert set(triggers) == {"takeover", "emergency_stop"}, rec.events
    assert 0 < triggers["emergency_stop"] - triggers["takeover"] <= 100_000
    recordings = log.events_of(EventKind.RECORDING)
    assert len(recordings) == 1 and sorted(recordings[0].data["triggers"]) == ["emergency_stop", "takeover"]


def test_every_channel_uses_a_foxglove_schema_or_a_documented_one_of_ours(
    estop_run: tuple[Path, RunLog],
) -> None:
    decoders = DecoderFactory()
    schemas: dict[str, str] = {}
    validators: dict[int, jsonschema.protocols.Validator] = {}
    with open(_recordings(estop_run)[0], "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            assert schema is not None, channel.topic
            schemas[channel.topic] = schema.name
            if schema.name.startswith("foxglove."):
                assert schema.name in FOXGLOVE_SCHEMAS, (channel.topic, schema.name)
                sdk = getattr(fm, schema.name.removeprefix("foxglove.")).get_schema()
                assert schema.encoding == "protobuf" and schema.data == sdk.data, channel.topic
                decoder = decoders.decoder_for(channel.message_encoding, schema)
                assert decoder is not None and decoder(message.data) is not None
            else:
                assert schema.name.startswith("lastmile."), (channel.topic, schema.name)
                assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
                if schema.id not in validators:
                    doc = json.loads(schema.data)
                    assert doc["title"] == schema.name and doc["description"], channel.topic
                    jsonschema.Draft202012Validator.check_schema(doc)
                    validators[schema.id] = jsonschema.Draft202012Validator(doc)
                validators[schema.id].validate(json.loads(message.data))
    # What an incident review needs is there, in Foxglove's own schemas.
    expected = {
        "/tf": "foxglove.FrameTransforms",
        "/pose": "foxglove.PoseInFrame",
        "/viz/tracking/tracks": "foxglove.SceneUpdate",
        "/viz/perception/detections": "foxglove.SceneUpdate",
        "/viz/planning/trajectory": "foxglove.SceneUpdate",
        "/viz/sensors/radar/front": "foxglove.PointCloud",
        "/route": "foxglove.SceneUpdate",
        "/map": "foxglove.SceneUpdate",
        "/log": "foxglove.Log",
        "/viz/sensors/traffic_lights/front": "foxglove.ImageAnnotations",
    }
    assert {t: schemas.get(t) for t in expected} == expected
    foxglove_share = sum(s.startswith("foxglove.") for s in schemas.values())
    assert foxglove_share >= 9, schemas


def test_the_detections_the_tracker_consumed_are_boxes_with_class_score_and_source(
    estop_run: tuple[Path, RunLog],
) -> None:
    decoders = DecoderFactory()
    entities = []
    lossless = 0
    with open(_recordings(estop_run)[0], "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(
            topics=["/viz/perception/detections", "/perception/detections"]
        ):
            if channel.topic == "/perception/detections":
                lossless += 1
                continue
            assert schema is not None
            entities += decoders.decoder_for(channel.message_encoding, schema)(message.data).entities  # type: ignore[misc]
    assert lossless > 0 and len(entities) > 0
    sources = set()
    for e in entities:
        meta = {kv.key: kv.value for kv in e.metadata}
        assert e.frame_id == "map" and len(e.cubes) == 1
        assert meta["class"] == "unknown" and 0.0 < float(meta["score"]) <= 1.0  # radar lists carry no class
        assert e.id.startswith(f"/perception/detections/{meta['source']}/")
        sources.add(meta["source"])
    # Both radars' object lists, each kept apart (one would otherwise replace the other in a viewer).
    assert sources == {"radar_front", "radar_rear"}


def _tree_and_frames(path: Path) -> tuple[dict[str, tuple[str, np.ndarray]], set[str]]:
    decoders = DecoderFactory()
    parents: dict[str, tuple[str, np.ndarray]] = {}
    used: set[str] = set()
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if schema is None or schema.encoding != "protobuf":
                continue
            msg = decoders.decoder_for(channel.message_encoding, schema)(message.data)  # type: ignore[misc]
            if schema.name == "foxglove.FrameTransforms":
                for tf in msg.transforms:
                    t = tf.translation
                    parents[tf.child_frame_id] = (tf.parent_frame_id, np.array([t.x, t.y, t.z]))
            elif schema.name in ("foxglove.PointCloud", "foxglove.PoseInFrame"):
                used.add(msg.frame_id)
            elif schema.name == "foxglove.SceneUpdate":
                used.update(e.frame_id for e in msg.entities)
    return parents, used


def test_tf_resolves_every_frame_id_used_with_the_true_radar_mounts(estop_run: tuple[Path, RunLog]) -> None:
    parents, used = _tree_and_frames(_recordings(estop_run)[0])
    assert {"map", "radar_front", "radar_rear"} <= used
    for frame in used | {"base_link"}:
        chain = [frame]
        while chain[-1] != "map":
            assert chain[-1] in parents, f"{frame}: no transform from {chain[-1]} towards map"
            chain.append(parents[chain[-1]][0])
            assert len(chain) < 8
    world = build_closed_loop(default_service(seed=0, minutes=0.1), RADAR).world
    for sensor_id, mount in world.radar_mounts.items():
        parent, t = parents[f"radar_{sensor_id}"]
        assert parent == "base_link" and np.allclose(t, [mount.x_m, mount.y_m, 0.0])


def test_the_mounts_are_every_lidar_camera_and_radar_of_the_vehicle_each_at_its_own_place() -> None:
    world = build_closed_loop(default_service(seed=0, minutes=0.1), RunConfig()).world
    calibration = sensor_calibration(world)
    mounts = sensor_frame_mounts(calibration)
    lidars = {k: m for k, m in mounts.items() if k.startswith("lidar_")}
    assert set(lidars) == {f"lidar_{s}" for s in calibration.lidar_mounts} and len(lidars) >= 1
    for sensor_id, m in calibration.lidar_mounts.items():
        assert np.array_equal(mounts[f"lidar_{sensor_id}"], m)
    for cam in calibration.cameras:
        # base_from_camera maps the optical centre to where the camera sits on the vehicle.
        centre = mounts[f"camera_{cam.camera_id}"] @ np.array([0.0, 0.0, 0.0, 1.0])
        assert np.allclose(centre[:3], cam.centre_base_m or centre[:3]) and centre[2] > 0.5
    radar = mounts["radar_front"][:3, 3]
    front_lidar = next(m for k, m in lidars.items())[:3, 3]
    assert not np.allclose(radar, front_lidar)  # no sensor borrows another's transform


def test_replay_render_draws_ego_tracks_and_path_and_never_overwrites(
    estop_run: tuple[Path, RunLog], tmp_path: Path
) -> None:
    path = _recordings(estop_run)[0]
    rec = read_recording(path)
    png = tmp_path / "incident.png"
    shot = render_png(rec, png)
    assert shot.fixed_frame == "map" and shot.ego and shot.boxes >= 1 and shot.lines >= 1, shot
    assert shot.cloud_points >= 1  # the radars' objects, placed through /tf
    rgb = mpimg.imread(png)[..., :3]
    ego_blue = np.all(np.abs(rgb - np.array([0.122, 0.467, 0.706])) < 0.08, axis=-1).sum()
    path_green = np.all(np.abs(rgb - np.array([0.1, 0.9, 0.3])) < 0.08, axis=-1).sum()
    assert ego_blue > 50 and path_green > 50, (ego_blue, path_green)
    result = CliRunner().invoke(app, ["replay", str(path), "--render", str(png)])
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and "exists (not overwritten)" in lines[0], result.output


def test_through_the_stack_the_recorded_inputs_give_the_recorded_commands(
    estop_run: tuple[Path, RunLog],
) -> None:
    # The file starts at t = 0, so a fresh stack fed its frames and the safety's directives (the
    # operator's e-stop among them) must reproduce every command and behaviour state exactly.
    path = _recordings(estop_run)[0]
    rec = read_recording(path)
    diff = replay_through_stack(rec)
    assert diff.ticks == len(rec.on("/stack/command")) > 300 and diff.compared == diff.ticks, diff
    assert any(d.emergency_stop for d in rec.on("/safety/directive"))  # the e-stop is in the replay
    assert diff.identical, diff
    result = CliRunner().invoke(app, ["replay", str(path), "--through-stack"])
    assert result.exit_code == 0 and "identical commands and behaviour states" in result.output, result.output


def test_through_the_stack_a_window_cut_mid_drive_says_where_it_differs(
    estop_run: tuple[Path, RunLog],
) -> None:
    rec = read_recording(_recordings(estop_run)[0])
    start = 3_000_000  # drop the first 3 s: the fresh stack starts without a pose, mid-drive
    cut = dataclasses.replace(rec, messages=tuple(m for m in rec.messages if m.log_time_us >= start))
    diff = replay_through_stack(cut)
    assert diff.differing > 0 and diff.first_diff_us is not None and diff.first_diff_us >= start, diff
