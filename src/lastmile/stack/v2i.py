"""Anticipation of crossings from infrastructure reports (NUS, Sec. V): slow down for a crossing the
roadside camera reports occupied, before the shuttle's own sensors can see it.

The camera sees the crossing from above (no occlusion by parked vans or pillars), so while it reports
pedestrians the shuttle aims to stop a little before the crosswalk, braking comfortably; when it
reports the crossing clear (or the report goes stale) the stop point is withdrawn and the shuttle's
own perception decides as before. A report that would need harder than comfortable braking is not
acted on: then the crossing is already within the onboard sensors' reach, and the decision machine's
own crosswalk yield (and its emergency stop) apply.
"""

from __future__ import annotations

from dataclasses import dataclass

from lastmile.core.config import check_range
from lastmile.core.sensor_frames import CrossingPresenceFrame
from lastmile.core.stamp import Stamp
from lastmile.hdmap.layers import RouteCrosswalk


@dataclass(frozen=True, slots=True, kw_only=True)
class AnticipationConfig:
    """Attributes:
    lookahead_m: reported crossings at most this far ahead of the front bumper are considered.
    max_age_s: a report captured longer ago than this is stale and ignored (NUS broadcast 5 Hz / 1 Hz).
    comfort_decel_mps2: the braking the anticipation may ask for; a nearer crossing is left to the
        onboard sensors.
    line_margin_m: the stop point's distance before the crosswalk's first edge.
    """

    lookahead_m: float = 60.0
    max_age_s: float = 2.5
    comfort_decel_mps2: float = 1.0
    line_margin_m: float = 1.0

    def __post_init__(self) -> None:
        check_range("v2i.lookahead_m", self.lookahead_m, 1.0, 500.0)
        check_range("v2i.max_age_s", self.max_age_s, 0.1, 60.0)
        check_range("v2i.comfort_decel_mps2", self.comfort_decel_mps2, 0.1, 5.0)
        check_range("v2i.line_margin_m", self.line_margin_m, 0.0, 10.0)


class CrossingAnticipation:
    """The newest report per crosswalk, and the stop point they ask for."""

    def __init__(
        self,
        crosswalks: tuple[RouteCrosswalk, ...],
        route_length_m: float,
        closed: bool,
        config: AnticipationConfig | None = None,
    ) -> None:
        self.crosswalks = crosswalks
        self.route_length_m = route_length_m
        self.closed = closed
        self.config = config or AnticipationConfig()
        self.reports: dict[int, CrossingPresenceFrame] = {}
        self.received = 0

    def on_frame(self, frame: CrossingPresenceFrame) -> None:
        old = self.reports.get(frame.crosswalk_id)
        if old is None or int(frame.captured) >= int(old.captured):  # out-of-order reports lose
            self.reports[frame.crosswalk_id] = frame
        self.received += 1

    def _ahead(self, s_m: float, front_s_m: float) -> float:
        ahead = s_m - front_s_m
        if self.closed:
            ahead %= self.route_length_m
        return ahead

    def stop_point(self, now: Stamp, front_s_m: float, speed_mps: float) -> float | None:
        """Route s (front bumper) to stop at for the nearest reported-occupied crossing ahead, or None."""
        c = self.config
        best: tuple[float, float] | None = None
        comfortable_m = speed_mps**2 / (2.0 * c.comfort_decel_mps2)
        for rc in self.crosswalks:
            report = self.reports.get(rc.crosswalk.id)
            if report is None or not report.pedestrians_present:
                continue
            if (int(now) - int(report.captured)) / 1e6 > c.max_age_s:
                continue
            line_s = rc.s_start_m - c.line_margin_m
            ahead = self._ahead(line_s, front_s_m)
            if not 0.0 < ahead <= c.lookahead_m or ahead < comfortable_m:
                continue
            if best is None or ahead < best[0]:
                best = (ahead, line_s)
        return None if best is None else best[1]

    def nearer(self, stop_s_m: float, other_s_m: float | None, front_s_m: float) -> bool:
        """Whether ``stop_s_m`` lies before ``other_s_m`` (None: no other stop) seen from the front.

        Signed distances (a stop point just behind the front, e.g. standing behind an obstacle, is
        nearer than any ahead), wrapped to half a loop on a closed route."""
        if other_s_m is None:
            return True
        return self._signed(stop_s_m, front_s_m) < self._signed(other_s_m, front_s_m)

    def _signed(self, s_m: float, front_s_m: float) -> float:
        d = s_m - front_s_m
        if self.closed:
            half = self.route_length_m / 2.0
            d = (d + half) % self.route_length_m - half
        return d
