"""The black box's channels served live over the Foxglove WebSocket protocol (the ``foxglove-sdk`` server).

``lastmile run --live`` starts it: Foxglove (the app, or any client of the protocol) connects to
``ws://HOST:PORT`` and sees the run as it happens, on the same topics and schemas as a black-box file
(``foxglove_views.py`` for the Foxglove channels, documented ``lastmile.*`` JSON for the rest). A
message is encoded only while some client subscribes to its channel, so an unwatched live view costs
the loop little more than the black box; each client's outgoing queue is bounded
(``message_backlog_size``), so a slow client loses old messages instead of stalling the run.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.vehicle_messages import LocalizationEstimate
from lastmile.recorder import foxglove_views as fv
from lastmile.recorder import mcap_codec
from lastmile.recorder.mcap_codec import ChannelSpec
from lastmile.recorder.topic_recorder import TopicRecorder


@dataclass(frozen=True, slots=True, kw_only=True)
class LiveViewConfig:
    """Attributes:
    host, port: where the WebSocket server listens (port 0: any free port, see :attr:`LiveView.port`).
    sensor_mounts, map_lines, route: as in :class:`~lastmile.recorder.black_box.BlackBoxConfig`.
    map_every_us: the map around the ego, the route and the sensor mounts are sent again this often,
        so a client that connects later gets them.
    message_backlog_size: messages queued per client before the oldest are dropped.
    """

    host: str = "127.0.0.1"
    port: int = 8765
    sensor_mounts: Mapping[str, np.ndarray] = field(default_factory=dict)
    map_lines: tuple[np.ndarray, ...] = ()
    route: np.ndarray | None = None
    map_every_us: int = 5_000_000
    message_backlog_size: int = 1024

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"live view port: expected 0..65535, got {self.port}")
        if self.map_every_us <= 0 or self.message_backlog_size <= 0:
            raise ConfigError(
                "live view: expected positive map_every_us and message_backlog_size, got "
                f"{self.map_every_us} and {self.message_backlog_size}"
            )


class LiveView(TopicRecorder):
    """A Foxglove WebSocket server publishing what the loop records, as it happens."""

    def __init__(self, config: LiveViewConfig) -> None:
        import foxglove

        super().__init__()
        self.config = config
        self._foxglove = foxglove
        self._ctx = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name="lastmile",
                host=config.host,
                port=config.port,
                context=self._ctx,
                message_backlog_size=config.message_backlog_size,
            )
        except RuntimeError as exc:
            raise ConfigError(
                f"--live: expected a free port to serve on at {config.host}:{config.port}, got {exc}"
            ) from None
        self._channels: dict[tuple[str, str], Any] = {}
        self._views = fv.ViewBuilder(
            sensor_mounts=config.sensor_mounts, map_lines=config.map_lines, route=config.route
        )
        self._next_map_us: int | None = None
        self._ego_xy = np.zeros((0, 2))

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self.server.port)

    def _channel(self, topic: str, spec: ChannelSpec) -> Any:
        key = (topic, spec.schema)
        ch = self._channels.get(key)
        if ch is None:
            schema = self._foxglove.Schema(
                name=spec.schema, encoding=spec.schema_encoding, data=spec.schema_data
            )
            ch = self._foxglove.Channel(
                topic, schema=schema, message_encoding=spec.message_encoding, context=self._ctx
            )
            self._channels[key] = ch
        return ch

    def _publish_views(self, views: Sequence[fv.View], now_us: int) -> None:
        for topic, msg in views:
            ch = self._channel(topic, mcap_codec.foxglove_spec(msg))
            if ch.has_sinks():
                ch.log(msg.encode(), log_time=now_us * 1000)

    def record(self, now_us: int, topic: str, message: Any) -> None:
        """Publish one message and its views (encoded only for channels a client subscribes to)."""
        if isinstance(message, LocalizationEstimate) and message.valid:
            self._ego_xy = np.array([[message.map_from_base.x_m, message.map_from_base.y_m]])
        if self._next_map_us is None or now_us >= self._next_map_us:
            self._next_map_us = now_us + self.config.map_every_us
            self._publish_views(list(self._views.opening(now_us, self._ego_xy)), now_us)
        if isinstance(message, LidarSweep):
            spec = mcap_codec.LIDAR_SPEC
            ch = self._channel(topic, spec)
            if ch.has_sinks():
                ch.log(mcap_codec.lossless_record(message)[1], log_time=now_us * 1000)
        else:
            spec = mcap_codec.json_spec(message)
            ch = self._channel(topic, spec)
            if ch.has_sinks():
                ch.log(mcap_codec.encode_message(message), log_time=now_us * 1000)
        self._publish_views(list(self._views.views(now_us, topic, message)), now_us)

    def close(self) -> None:
        """Stop the server (clients are disconnected)."""
        self.server.stop()
