"""``lastmile run --live``: the black box's channels served over the Foxglove WebSocket protocol."""

from __future__ import annotations

import base64
import dataclasses
import json
import struct
import time
from pathlib import Path

import pytest
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory
from websockets.sync.client import connect

from lastmile.core.errors import ConfigError
from lastmile.recorder.foxglove_views import planar_matrix
from lastmile.recorder.live_view import LiveView, LiveViewConfig
from lastmile.runner.closed_loop import run_scenario
from lastmile.sim.scenario import default_service
from tests.closed_loop.harness import RADAR
from tests.recorder.foxglove_ws import advertised
from tests.recorder.stream import record_ticks

MOUNTS = {"lidar_top": planar_matrix(1.2, 0.0, 0.0, 1.9), "radar_front": planar_matrix(3.75, 0.0, 0.0)}


def _advertised(ws: object, wanted: set[str], timeout_s: float = 10.0) -> dict[str, dict]:
    return advertised(ws, wanted, timeout_s)


def test_a_client_sees_the_channels_and_gets_the_transform_tree_it_subscribes_to() -> None:
    live = LiveView(LiveViewConfig(port=0, sensor_mounts=MOUNTS))
    try:
        ticks = record_ticks(live, 0, 10_000, lidar_points=20)  # type: ignore[arg-type]
        for _ in range(20):
            next(ticks)
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
            channels = _advertised(ws, {"/tf", "/pose", "/viz/tracking/tracks", "/stack/command"})
            assert channels["/tf"]["schemaName"] == "foxglove.FrameTransforms"
            assert channels["/stack/command"]["schemaName"] == "lastmile.ActuatorCommand"
            tf = channels["/tf"]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": tf["id"]}]}))
            payload = None
            deadline = time.monotonic() + 10.0
            while payload is None and time.monotonic() < deadline:
                for _ in range(10):
                    next(ticks)
                try:
                    msg = ws.recv(timeout=0.05)
                except TimeoutError:
                    continue
                if isinstance(msg, bytes) and msg[0] == 0x01:
                    sub_id, _log_ns = struct.unpack_from("<IQ", msg, 1)
                    assert sub_id == 7
                    payload = msg[13:]
        assert payload is not None, "no /tf message within 10 s of subscribing"
        schema = Schema(id=1, name=tf["schemaName"], encoding="protobuf", data=base64.b64decode(tf["schema"]))
        decoded = DecoderFactory().decoder_for("protobuf", schema)(payload)  # type: ignore[misc]
        children = {t.child_frame_id: t.parent_frame_id for t in decoded.transforms}
        assert children == {"base_link": "map", "lidar_top": "base_link", "radar_front": "base_link"}
    finally:
        live.close()


def test_a_run_served_live_is_paced_to_the_wall_clock_and_a_bad_port_is_one_clear_error(
    tmp_path: Path,
) -> None:
    scenario = dataclasses.replace(default_service(seed=0), minutes=1.0 / 60.0)
    ports: list[int] = []
    t0 = time.perf_counter()
    log = run_scenario(scenario, RADAR, live=("127.0.0.1", 0), on_live=ports.append)
    assert time.perf_counter() - t0 >= 1.0  # one simulated second took at least one second
    assert len(ports) == 1 and ports[0] > 0 and log.ego[-1, 0] > 0.9
    with pytest.raises(ConfigError, match=r"port: expected 0\.\.65535, got 70000"):
        LiveViewConfig(port=70000)
