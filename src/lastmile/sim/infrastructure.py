"""Infrastructure sensors (NUS): a camera at a crossing that broadcasts pedestrian presence to the fleet.

The node sees the crossing from above, so occlusion by parked vehicles or pillars does not affect it;
it publishes at its own rate (NUS: 5 Hz, and a 1 Hz variant) with a network latency and may miss a
pedestrian now and then.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lastmile.core.config import check_range


@dataclass(frozen=True, slots=True, kw_only=True)
class CrossingCameraConfig:
    """An infrastructure camera node.

    Attributes:
        rate_hz: broadcast rate (NUS ran 5 Hz and 1 Hz).
        latency_s: from capture to the vehicle's radio.
        miss_probability: chance that one broadcast misses a pedestrian who is there.
    """

    rate_hz: float = 5.0
    latency_s: float = 0.1
    miss_probability: float = 0.02

    def __post_init__(self) -> None:
        check_range("crossing_camera.rate_hz", self.rate_hz, 0.1, 100.0)
        check_range("crossing_camera.latency_s", self.latency_s, 0.0, 5.0)
        check_range("crossing_camera.miss_probability", self.miss_probability, 0.0, 1.0)


@dataclass(frozen=True, slots=True)
class PresenceMessage:
    """What the node broadcasts: whether pedestrians are on (or stepping onto) the crossing."""

    captured_s: float
    received_s: float
    pedestrians_present: bool


class CrossingCamera:
    """Samples presence at its rate; the vehicle sees the newest message whose latency has elapsed."""

    def __init__(self, config: CrossingCameraConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._rng = rng
        self._next_capture_s = 0.0
        self._in_flight: list[PresenceMessage] = []
        self.latest: PresenceMessage | None = None

    def step(self, t_s: float, truly_present: bool) -> None:
        c = self.config
        if t_s + 1e-9 >= self._next_capture_s:
            seen = truly_present and self._rng.random() >= c.miss_probability
            self._in_flight.append(PresenceMessage(t_s, t_s + c.latency_s, seen))
            self._next_capture_s += 1.0 / c.rate_hz
        while self._in_flight and self._in_flight[0].received_s <= t_s + 1e-9:
            self.latest = self._in_flight.pop(0)
