"""Traffic-light detector frames are recorded on their own topic and decode back losslessly."""

from __future__ import annotations

import numpy as np

from lastmile.core.stamp import Stamp
from lastmile.core.traffic_light_messages import TrafficLightDetections
from lastmile.recorder import mcap_codec
from lastmile.recorder.black_box import sensor_topic


def test_light_detections_round_trip_through_the_codec_on_their_topic() -> None:
    frame = TrafficLightDetections(
        stamp=Stamp(1_230_000), camera_id="front", boxes=np.array([[10.5, 20.0, 19.5, 45.0]]),
        states=np.array([1], dtype=np.int64), scores=np.array([0.83]),
    )  # fmt: skip
    spec, data = mcap_codec.lossless_record(frame)
    assert spec.schema == "lastmile.TrafficLightDetections" and spec.message_encoding == "json"
    back = mcap_codec.decode_message(spec.schema, data)
    assert isinstance(back, TrafficLightDetections) and back.stamp == frame.stamp
    assert np.array_equal(back.boxes, frame.boxes) and np.array_equal(back.states, frame.states)
    assert np.array_equal(back.scores, frame.scores)
    assert sensor_topic(frame) == "/sensors/traffic_lights/front"
