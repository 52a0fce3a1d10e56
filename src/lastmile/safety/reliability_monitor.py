"""WATonoBus's reliability monitor: location (ODD), weather, sensor performance and localization integrity."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

from lastmile.core.polyline import Polyline
from lastmile.core.safety_messages import (
    FailSafeLevel,
    MalfunctionKind,
    MalfunctionSignal,
    SensorDiagnostics,
    WeatherReport,
)
from lastmile.core.sensor_frames import (
    GnssInsFrame,
    SensorFrame,
)
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.hdmap.model import HDMap
from lastmile.safety.frame_checks import garbage_reason, payload_digest, point_count, sensor_key
from lastmile.safety.reliability_config import ReliabilityConfig, SensorSpec

K = MalfunctionKind
L = FailSafeLevel

_MAP_SOURCES = (PositionSource.LANDMARKS, PositionSource.SCAN_MATCHING, PositionSource.AMCL)
"""Sources that hold the pose to the map without GNSS (a lost fix then limits nothing)."""


class _Stream:
    __slots__ = (
        "arrivals",
        "digest",
        "events",
        "first_us",
        "last_arrival_us",
        "last_stamp_us",
        "latency_min_us",
        "out_of_order",
        "period_us",
        "points_low",
        "repeats",
        "source",
        "spec",
        "timeout_us",
    )

    def __init__(self, spec: SensorSpec, config: ReliabilityConfig) -> None:
        self.spec = spec
        # Fixed per stream: worked out once, not on every check.
        self.source = f"sensor:{spec.key}"
        self.period_us = spec.period_us
        self.timeout_us = config.silent_factor * self.period_us + config.silent_margin_us
        self.arrivals: deque[int] = deque()
        self.last_arrival_us = -1
        self.last_stamp_us = -1
        self.latency_min_us: int | None = None
        self.first_us = -1
        self.digest: tuple[object, ...] | None = None
        self.repeats = 0
        self.points_low = False
        self.out_of_order: deque[int] = deque()
        # kind -> (last event time, reason) for one-off events held for event_hold_us.
        self.events: dict[MalfunctionKind, tuple[int, str]] = {}

    def arrive(self, now_us: int, window_us: int) -> None:
        """A frame arrived: its time counts towards the rate over the last ``window_us``."""
        if self.first_us < 0:
            self.first_us = now_us
        self.last_arrival_us = now_us
        self.arrivals.append(now_us)
        while self.arrivals and self.arrivals[0] <= now_us - window_us:
            self.arrivals.popleft()

    def check_timing(self, now_us: int, stamp_us: int, config: ReliabilityConfig) -> None:
        """Latency against the stream's bound, and stamps going back (out of order) within the window."""
        latency = now_us - stamp_us
        if latency > self.spec.max_latency_us:
            self.events[K.SENSOR_LATENCY] = (
                now_us,
                f"latency {latency / 1e3:.0f} ms > {self.spec.max_latency_us / 1e3:.0f} ms",
            )
        if stamp_us > self.last_stamp_us:
            self.last_stamp_us = stamp_us
            if self.latency_min_us is None or latency < self.latency_min_us:
                self.latency_min_us = latency
            return
        self.out_of_order.append(now_us)
        while self.out_of_order and self.out_of_order[0] <= now_us - config.rate_window_us:
            self.out_of_order.popleft()
        if len(self.out_of_order) > config.out_of_order_max:
            self.events[K.SENSOR_OUT_OF_ORDER] = (
                now_us,
                f"{len(self.out_of_order)} stamps going back within {config.rate_window_us / 1e6:.0f} s, "
                f"last {stamp_us} after {self.last_stamp_us}",
            )

    def check_content(self, frame: SensorFrame) -> None:
        """A payload repeating its predecessor (a frozen driver), and too few points or detections."""
        if self.spec.frozen_after is not None:
            digest = payload_digest(frame)
            if digest is not None and digest == self.digest:
                self.repeats += 1
            else:
                self.repeats = 1 if digest is not None else 0
            self.digest = digest
        count = point_count(frame)
        if self.spec.min_points > 0 and count is not None:
            self.points_low = count < self.spec.min_points


class ReliabilityMonitor:
    """Checks the inputs the stack depends on against the ODD and emits prioritised malfunction signals.

    Feed it everything the stack receives (``observe_*``) and call :meth:`evaluate` once per check
    (every base tick or every planning cycle); it returns the malfunctions active now. It keeps no
    latch of its own: latching and hysteresis are the fail-safe arbiter's job.
    """

    def __init__(
        self,
        config: ReliabilityConfig | None = None,
        hdmap: HDMap | None = None,
        route: Polyline | None = None,
        lane_margin_m: Callable[[float], float] | None = None,
    ) -> None:
        """Args:
        lane_margin_m: the lane margin (half the lane width less half the vehicle's) at a route s of
            the rear axle, m; None: ``config.lane_margin_m``.
        """
        self.config = config or ReliabilityConfig()
        self.lane_margin_m = lane_margin_m
        self._dead_reckoning_stopped = False
        self.hdmap = hdmap
        self.route = route
        if hdmap is not None:
            # The map builds its drivable raster on first use (about a second): do it now, not mid-drive.
            hdmap.is_drivable(np.zeros((1, 2)))
        self._streams = {s.key: _Stream(s, self.config) for s in self.config.sensors}
        self._unknown_garbage: dict[str, tuple[int, str]] = {}
        self._started_us: int | None = None
        self._pose: LocalizationEstimate | None = None
        self._pose_at_us = -1
        self._ever_valid = False
        self._route_s: float | None = None
        self._location_for_us = -1
        self._location_found: list[tuple[MalfunctionKind, str]] = []
        self._last_fix_us: int | None = None
        self._fix_dropped_us: int | None = None
        self._gnss_seen = False
        self._gate: deque[tuple[int, int]] = deque()
        self._gate_total: int | None = None
        self._gross: deque[tuple[int, int]] = deque()
        self._gross_total: int | None = None
        self._weather: WeatherReport | None = None
        self._diagnostics: dict[str, SensorDiagnostics] = {}

    # --- inputs ------------------------------------------------------------------------------------
    def observe_frame(self, now_us: int, frame: SensorFrame) -> None:
        """Every sensor frame the stack receives, at its arrival time ``now_us``."""
        self._start(now_us)
        key = sensor_key(frame)
        if key is None:
            return
        now = int(now_us)
        bad = garbage_reason(frame)
        st = self._streams.get(key)
        if st is None:
            if bad:
                self._unknown_garbage[key] = (now, bad)
            return
        st.arrive(now, self.config.rate_window_us)
        if bad:
            st.events[K.SENSOR_GARBAGE] = (now, bad)
            return  # garbage says nothing about freezing, latency or order
        st.check_timing(now, int(frame.stamp), self.config)
        st.check_content(frame)
        if isinstance(frame, GnssInsFrame):
            self._observe_fix(now, frame)

    def _observe_fix(self, now_us: int, frame: GnssInsFrame) -> None:
        self._gnss_seen = True
        if frame.fix_ok:
            self._last_fix_us = now_us
            self._fix_dropped_us = None
        elif self._fix_dropped_us is None:
            self._fix_dropped_us = now_us

    def observe_localization(self, now_us: int, estimate: LocalizationEstimate) -> None:
        """The EKF's estimate (once per check is enough)."""
        self._start(now_us)
        self._pose = estimate
        self._pose_at_us = int(now_us)
        self._ever_valid |= estimate.valid

    def observe_gate_rejections(
        self, now_us: int, rejected_total: int, gross_total: int | None = None
    ) -> None:
        """The EKF's cumulative counts of fixes its chi-square gate rejected (``PoseEkf.rejected_fixes``)
        and of those far beyond it (``PoseEkf.gross_rejections``; None: not reported)."""
        self._start(now_us)
        if self._gate_total is not None and rejected_total > self._gate_total:
            self._gate.append((int(now_us), rejected_total - self._gate_total))
        self._gate_total = rejected_total
        if gross_total is not None:
            if self._gross_total is not None and gross_total > self._gross_total:
                self._gross.append((int(now_us), gross_total - self._gross_total))
            self._gross_total = gross_total

    def observe_weather(self, report: WeatherReport) -> None:
        report.validate()
        self._weather = report

    def observe_diagnostics(self, diagnostics: SensorDiagnostics) -> None:
        diagnostics.validate()
        self._diagnostics[diagnostics.sensor_id] = diagnostics

    def _start(self, now_us: int) -> None:
        if self._started_us is None:
            self._started_us = int(now_us)

    # --- output ------------------------------------------------------------------------------------
    def evaluate(self, now_us: int) -> tuple[MalfunctionSignal, ...]:
        """The malfunctions active at ``now_us``, each with its fail-safe level."""
        self._start(now_us)
        out: list[MalfunctionSignal] = []
        self._sensors(now_us, out)
        self._location(now_us, out)
        self._localization(now_us, out)
        self._weather_checks(now_us, out)
        return tuple(out)

    def _emit(
        self,
        out: list[MalfunctionSignal],
        now_us: int,
        source: str,
        kind: MalfunctionKind,
        reason: str,
        level: FailSafeLevel | None = None,
        cap: float | None = None,
    ) -> None:
        out.append(
            MalfunctionSignal(
                stamp=Stamp(int(now_us)),
                source=source,
                kind=kind,
                level=self.config.level(kind) if level is None else level,
                reason=f"{source}: {reason}",
                speed_cap_mps=cap,
            )
        )

    def _sensors(self, now_us: int, out: list[MalfunctionSignal]) -> None:
        c = self.config
        assert self._started_us is not None
        for st in self._streams.values():
            src, spec, timeout = st.source, st.spec, st.timeout_us
            if st.last_arrival_us < 0:
                if now_us - self._started_us > max(timeout, c.startup_grace_us):
                    self._emit(out, now_us, src, K.SENSOR_SILENT, "no frame received yet", spec.silent_level)
                continue
            if now_us - st.last_arrival_us > timeout:
                self._emit(
                    out,
                    now_us,
                    src,
                    K.SENSOR_SILENT,
                    f"no frame for {(now_us - st.last_arrival_us) / 1e3:.0f} ms "
                    f"(timeout {timeout / 1e3:.0f} ms)",
                    spec.silent_level,
                )
                continue
            if st.latency_min_us is not None and K.SENSOR_LATENCY not in st.events:
                # The next frame is due one period after the last stamp, plus the stream's own latency:
                # a frame that late is a latency fault well before the stream counts as silent.
                due_us = st.last_stamp_us + st.period_us + st.latency_min_us + c.overdue_margin_us
                if now_us > due_us:
                    self._emit(
                        out,
                        now_us,
                        src,
                        K.SENSOR_LATENCY,
                        f"next frame overdue by {(now_us - due_us + c.overdue_margin_us) / 1e3:.0f} ms",
                    )
            while st.arrivals and st.arrivals[0] <= now_us - c.rate_window_us:
                st.arrivals.popleft()
            if now_us - st.first_us >= c.rate_window_us:
                rate = len(st.arrivals) / (c.rate_window_us / 1e6)
                if rate < c.min_rate_fraction * spec.rate_hz:
                    self._emit(
                        out,
                        now_us,
                        src,
                        K.SENSOR_RATE_LOW,
                        f"{rate:.1f} Hz < {c.min_rate_fraction:.0%} of {spec.rate_hz:.1f} Hz",
                    )
            if spec.frozen_after is not None and st.repeats >= spec.frozen_after:
                self._emit(
                    out,
                    now_us,
                    src,
                    K.SENSOR_FROZEN,
                    f"{st.repeats} identical frames in a row",
                    spec.frozen_level,
                )
            if st.points_low:
                self._emit(
                    out,
                    now_us,
                    src,
                    K.SENSOR_BLOCKAGE,
                    f"fewer than {spec.min_points} points (LiDAR) or raw reflections (radar) per cycle",
                )
            for kind, (at_us, reason) in list(st.events.items()) if st.events else ():
                if now_us - at_us >= c.event_hold_us:
                    del st.events[kind]
                    continue
                self._emit(out, now_us, src, kind, reason)
        for key, (at_us, reason) in list(self._unknown_garbage.items()):
            if now_us - at_us < c.event_hold_us:
                self._emit(out, now_us, f"sensor:{key}", K.SENSOR_GARBAGE, reason)
            else:
                del self._unknown_garbage[key]
        for key, d in self._diagnostics.items():
            if d.blockage_fraction > c.blockage_max:
                self._emit(
                    out,
                    now_us,
                    f"sensor:{key}",
                    K.SENSOR_BLOCKAGE,
                    f"blockage {d.blockage_fraction:.0%} > {c.blockage_max:.0%}",
                )
            if d.noise_level > c.noise_max:
                self._emit(
                    out,
                    now_us,
                    f"sensor:{key}",
                    K.SENSOR_NOISE,
                    f"noise {d.noise_level:.0%} > {c.noise_max:.0%}",
                )

    def _location(self, now_us: int, out: list[MalfunctionSignal]) -> None:
        est = self._pose
        if est is None or not est.valid:
            return
        if self._location_for_us != self._pose_at_us:
            # The map and route look-ups cost tens of microseconds: once per new pose, not per check.
            self._location_for_us = self._pose_at_us
            self._location_found = self._location_faults(est)
        for kind, reason in self._location_found:
            self._emit(out, now_us, "odd", kind, reason)

    def _location_faults(self, est: LocalizationEstimate) -> list[tuple[MalfunctionKind, str]]:
        found: list[tuple[MalfunctionKind, str]] = []
        pose = est.map_from_base
        if self.hdmap is not None and not bool(self.hdmap.is_drivable(np.array([[pose.x_m, pose.y_m]]))[0]):
            found.append((K.OFF_MAP, f"pose ({pose.x_m:.1f}, {pose.y_m:.1f}) not on a drivable lanelet"))
        if self.route is not None:
            limit = self.config.route_offset_max_m
            f = self.route.project(pose.x_m, pose.y_m, hint_s_m=self._route_s, window_m=30.0)
            if abs(f.d_m) > limit:
                # The windowed projection may have lost the route; confirm with a global one.
                f = self.route.project(pose.x_m, pose.y_m)
            self._route_s = f.s_m
            if abs(f.d_m) > limit:
                found.append((K.OFF_ROUTE, f"{abs(f.d_m):.1f} m from the route > {limit:.1f} m"))
        return found

    def _localization(self, now_us: int, out: list[MalfunctionSignal]) -> None:
        c = self.config
        assert self._started_us is not None
        after_grace = now_us - self._started_us > c.startup_grace_us
        est = self._pose
        if est is not None:
            if not est.valid:
                if self._ever_valid or after_grace:
                    self._emit(out, now_us, "localization", K.LOCALIZATION_INVALID, "no valid pose estimate")
            else:
                self._pose_integrity(now_us, est, out)
        elif after_grace:
            self._emit(out, now_us, "localization", K.LOCALIZATION_INVALID, "no pose estimate received")
        if self._gnss_seen or after_grace:
            self._gnss_lost(now_us, out)
        while self._gate and self._gate[0][0] <= now_us - c.gate_window_us:
            self._gate.popleft()
        rejected = sum(n for _, n in self._gate)
        while self._gross and self._gross[0][0] <= now_us - c.gate_window_us:
            self._gross.popleft()
        gross = sum(n for _, n in self._gross)
        if gross > c.gross_rejections_max and rejected <= c.gate_rejections_max:
            self._emit(
                out,
                now_us,
                "localization",
                K.LOCALIZATION_GATE_REJECTIONS,
                f"{gross} GNSS fix(es) over 20 sigma off the estimate in {c.gate_window_us / 1e6:.0f} s",
            )
        if rejected > c.gate_rejections_max:
            self._emit(
                out,
                now_us,
                "localization",
                K.LOCALIZATION_GATE_REJECTIONS,
                f"{rejected} GNSS fixes rejected by the EKF gate in {c.gate_window_us / 1e6:.0f} s",
            )

    def _pose_integrity(self, now_us: int, est: LocalizationEstimate, out: list[MalfunctionSignal]) -> None:
        """A valid pose's covariance against the lane margin and the covariance limits; dead reckoning."""
        c = self.config
        if self._beyond_lane_margin(now_us, est, out):
            pass  # the manoeuvre to a stop covers the covariance limits below
        elif est.pos_std_m > c.pos_std_max_m:
            self._emit(
                out,
                now_us,
                "localization",
                K.LOCALIZATION_COVARIANCE,
                f"position std {est.pos_std_m:.2f} m > {c.pos_std_max_m:.2f} m",
                FailSafeLevel.MINIMAL_RISK_MANOEUVRE,
            )
        elif est.pos_std_m > c.pos_std_degraded_m:
            self._emit(
                out,
                now_us,
                "localization",
                K.LOCALIZATION_COVARIANCE,
                f"position std {est.pos_std_m:.2f} m > {c.pos_std_degraded_m:.2f} m",
                cap=c.covariance_speed_cap_mps,
            )
        self._dead_reckoning(now_us, est, out)

    def _beyond_lane_margin(
        self, now_us: int, est: LocalizationEstimate, out: list[MalfunctionSignal]
    ) -> bool:
        """The position's protection level beyond the lane margin: the MRM to a stop (the vehicle can no
        longer tell that it is in its lane)."""
        c = self.config
        margin = c.lane_margin_m
        if self.lane_margin_m is not None and self._route_s is not None:
            margin = self.lane_margin_m(self._route_s)
        level_m = c.protection_sigma_factor * est.pos_std_m
        if margin is None or level_m <= margin:
            return False
        self._emit(
            out,
            now_us,
            "localization",
            K.LOCALIZATION_COVARIANCE,
            f"protection level {c.protection_sigma_factor:.2f} sigma = {level_m:.2f} m "
            f"> lane margin {margin:.2f} m",
            FailSafeLevel.MINIMAL_RISK_MANOEUVRE,
        )
        return True

    def _dead_reckoning(self, now_us: int, est: LocalizationEstimate, out: list[MalfunctionSignal]) -> None:
        """While nothing absolute holds the pose: Snow Lion's 0.5 m/s, and 0 once the vehicle has stopped
        until a fix or a landmark holds the pose again. A vehicle that has lost its position slows to the
        cap; it never speeds up beyond it, and never moves off again on dead reckoning. (A cap that
        followed the lowest speed down would spiral to a stop: the stack tracks the cap from below.)"""
        c = self.config
        if est.source is not PositionSource.DEAD_RECKONING:
            self._dead_reckoning_stopped = False
            return
        if abs(est.speed_mps) < c.standstill_mps:
            self._dead_reckoning_stopped = True
        held = self._dead_reckoning_stopped
        self._emit(
            out,
            now_us,
            "localization",
            K.LOCALIZATION_DEAD_RECKONING,
            "no absolute position correction: dead reckoning" + (", held at standstill" if held else ""),
            cap=0.0 if held else c.covariance_speed_cap_mps,
        )

    def _gnss_lost(self, now_us: int, out: list[MalfunctionSignal]) -> None:
        """No fix (the receiver says so, or none for ``gnss_lost_us``): Snow Lion's cap while the pose
        dead-reckons; nothing to enforce while landmarks hold it (the signal is kept for the record)."""
        c = self.config
        assert self._started_us is not None
        since = self._last_fix_us if self._last_fix_us is not None else self._started_us
        if now_us - since > c.gnss_lost_us:
            reason = f"no GNSS fix for {(now_us - since) / 1e6:.1f} s"
        elif self._last_fix_us is not None and self._fix_dropped_us is not None:
            reason = "GNSS receiver reports no fix"
        else:
            return
        est = self._pose
        if est is not None and est.valid and est.source in _MAP_SOURCES:
            self._emit(
                out,
                now_us,
                "sensor:gnss",
                K.GNSS_LOST,
                reason + f" (pose held by {est.source.value.replace('_', ' ')})",
                FailSafeLevel.NONE,
            )
            return
        self._emit(out, now_us, "sensor:gnss", K.GNSS_LOST, reason, cap=c.covariance_speed_cap_mps)

    def _weather_checks(self, now_us: int, out: list[MalfunctionSignal]) -> None:
        w, c = self._weather, self.config
        if w is None:
            return
        if w.visibility_m < c.visibility_min_m:
            self._emit(
                out,
                now_us,
                "odd",
                K.WEATHER_VISIBILITY,
                f"visibility {w.visibility_m:.0f} m < {c.visibility_min_m:.0f} m",
            )
        elif w.visibility_m < c.visibility_degraded_m:
            self._emit(
                out,
                now_us,
                "odd",
                K.WEATHER_VISIBILITY,
                f"visibility {w.visibility_m:.0f} m < {c.visibility_degraded_m:.0f} m",
                FailSafeLevel.SPEED_LIMIT,
                c.weather_speed_cap_mps,
            )
        if w.precipitation_mmph > c.precipitation_max_mmph:
            self._emit(
                out,
                now_us,
                "odd",
                K.WEATHER_PRECIPITATION,
                f"precipitation {w.precipitation_mmph:.1f} mm/h > {c.precipitation_max_mmph:.1f} mm/h",
                cap=c.weather_speed_cap_mps,
            )
        elif w.precipitation_mmph > c.precipitation_degraded_mmph:
            self._emit(
                out,
                now_us,
                "odd",
                K.WEATHER_PRECIPITATION,
                f"precipitation {w.precipitation_mmph:.1f} mm/h > {c.precipitation_degraded_mmph:.1f} mm/h",
                FailSafeLevel.SPEED_LIMIT,
                c.weather_speed_cap_mps,
            )
