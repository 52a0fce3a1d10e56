"""Reliability monitor: each malfunction is detected from the inputs and mapped to its fail-safe level."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.safety_messages import (
    FailSafeLevel,
    MalfunctionKind,
    MalfunctionSignal,
    SensorDiagnostics,
    WeatherReport,
)
from lastmile.core.sensor_frames import GnssInsFrame, ImuFrame, LidarSweep, RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.hdmap.model import HDMap
from lastmile.safety.reliability_config import ReliabilityConfig, SensorSpec
from lastmile.safety.reliability_monitor import ReliabilityMonitor

K, L = MalfunctionKind, FailSafeLevel
TICK = 10_000


def _specs() -> tuple[SensorSpec, ...]:
    return (
        SensorSpec(key="gnss", rate_hz=10.0),
        SensorSpec(key="imu", rate_hz=50.0, frozen_after=10),
        SensorSpec(key="radar_front", rate_hz=20.0),
        SensorSpec(key="lidar_top", rate_hz=10.0, min_points=100),
    )


class Feed:
    """A healthy sensor suite at its rates; hooks can break one stream from a given time."""

    def __init__(
        self,
        hdmap: HDMap | None = None,
        config: ReliabilityConfig | None = None,
        lane_margin_m: Callable[[float], float] | None = None,
    ) -> None:
        route = Polyline(np.array([[0.0, 0.0], [400.0, 0.0]]))
        self.mon = ReliabilityMonitor(
            config or ReliabilityConfig(sensors=_specs()),
            hdmap=hdmap,
            route=route,
            lane_margin_m=lane_margin_m,
        )
        self.speed_mps = 3.0
        self.source = PositionSource.GNSS
        self.rng = np.random.default_rng(0)
        self.now = 0
        self.x_m = 50.0
        self.y_m = 0.0
        self.pos_std_m = 0.05
        self.valid = True
        self.fix_ok = True
        self.break_gnss: Callable[[int], GnssInsFrame | None] | None = None
        self.break_imu: Callable[[int], ImuFrame | None] | None = None
        self.break_radar: Callable[[int], RadarFrame | None] | None = None
        self.lidar_points = 2000

    def run(self, until_us: int) -> tuple[MalfunctionSignal, ...]:
        signals: tuple[MalfunctionSignal, ...] = ()
        while self.now <= until_us:
            t = self.now
            if t % 100_000 == 0:
                g = GnssInsFrame(
                    stamp=Stamp(t - 30_000),
                    x_m=self.x_m + self.rng.normal(0, 0.02),
                    y_m=self.y_m,
                    yaw_rad=0.0,
                    speed_mps=3.0,
                    pos_std_m=0.02,
                    yaw_std_rad=0.004,
                    fix_ok=self.fix_ok,
                )
                frame = self.break_gnss(t) if self.break_gnss else g
                if frame is not None:
                    self.mon.observe_frame(t, frame)
                pts = self.rng.normal(size=(self.lidar_points, 6)).astype(np.float32)
                self.mon.observe_frame(t, LidarSweep(stamp=Stamp(t - 50_000), sensor_id="top", points=pts))
            if t % 20_000 == 0:
                imu = ImuFrame(
                    stamp=Stamp(t - 4_000),
                    yaw_rate_radps=self.rng.normal(0, 0.003),
                    accel_x_mps2=0.0,
                    accel_y_mps2=0.0,
                )
                frame_i = self.break_imu(t) if self.break_imu else imu
                if frame_i is not None:
                    self.mon.observe_frame(t, frame_i)
            if t % 50_000 == 0:
                radar = RadarFrame(
                    stamp=Stamp(t - 45_000), sensor_id="radar_front", objects=self.rng.normal(size=(3, 6))
                )
                frame_r = self.break_radar(t) if self.break_radar else radar
                if frame_r is not None:
                    self.mon.observe_frame(t, frame_r)
            if t % 100_000 == 0:
                self.mon.observe_localization(
                    t,
                    LocalizationEstimate(
                        stamp=Stamp(t),
                        map_from_base=SE2(self.x_m, self.y_m, 0.0),
                        speed_mps=self.speed_mps,
                        yaw_rate_radps=0.0,
                        pos_std_m=self.pos_std_m,
                        yaw_std_rad=0.01,
                        valid=self.valid,
                        source=self.source,
                    ),
                )
            signals = self.mon.evaluate(t)
            self.now += TICK
        return signals


def _only(signals: tuple[MalfunctionSignal, ...], kind: MalfunctionKind) -> MalfunctionSignal:
    found = [s for s in signals if s.kind == kind]
    assert len(found) == 1, signals
    return found[0]


def test_healthy_suite_on_the_route_raises_nothing(straight_map: HDMap) -> None:
    feed = Feed(straight_map)
    assert feed.run(5_000_000) == ()


def test_dead_sensor_is_silent_within_one_period_plus_100_ms() -> None:
    feed = Feed()
    assert feed.run(3_000_000) == ()
    feed.break_radar = lambda t: None
    died = feed.now
    seen: list[MalfunctionKind] = []
    while True:
        signals = feed.run(feed.now)
        seen += [s.kind for s in signals]
        if any(s.kind == K.SENSOR_SILENT for s in signals):
            break
    sig = _only(signals, K.SENSOR_SILENT)
    assert sig.source == "sensor:radar_front" and sig.level == L.MINIMAL_RISK_MANOEUVRE
    assert feed.now - TICK - died <= 50_000 + 100_000
    # Before it counts as silent, its overdue frame is a latency fault, and nothing else.
    assert set(seen) <= {K.SENSOR_LATENCY, K.SENSOR_SILENT}


def test_each_sensor_fault_maps_to_its_level() -> None:
    cases: list[tuple[str, MalfunctionKind, FailSafeLevel]] = []
    # Frozen IMU driver: the same payload over and over (new stamps).
    feed = Feed()
    feed.run(2_500_000)
    stuck = ImuFrame(stamp=Stamp(0), yaw_rate_radps=0.0123, accel_x_mps2=0.1, accel_y_mps2=0.0)
    feed.break_imu = lambda t: ImuFrame(
        stamp=Stamp(t - 4_000), yaw_rate_radps=stuck.yaw_rate_radps, accel_x_mps2=0.1, accel_y_mps2=0.0
    )
    sig = _only(feed.run(feed.now + 300_000), K.SENSOR_FROZEN)
    cases.append((sig.source, sig.kind, sig.level))
    # Garbage: a NaN position from the GNSS driver.
    feed = Feed()
    feed.run(2_500_000)
    feed.break_gnss = lambda t: GnssInsFrame(
        stamp=Stamp(t - 30_000),
        x_m=float("nan"),
        y_m=0.0,
        yaw_rad=0.0,
        speed_mps=3.0,
        pos_std_m=0.02,
        yaw_std_rad=0.004,
    )
    sig = _only(feed.run(feed.now + 100_000), K.SENSOR_GARBAGE)
    assert "x_m" in sig.reason
    cases.append((sig.source, sig.kind, sig.level))
    # Latency spike: radar frames arriving 400 ms after capture.
    feed = Feed()
    feed.run(2_500_000)
    feed.break_radar = lambda t: RadarFrame(stamp=Stamp(t - 400_000), sensor_id="radar_front")
    sig = _only(feed.run(feed.now + 100_000), K.SENSOR_LATENCY)
    cases.append((sig.source, sig.kind, sig.level))
    # Out-of-order stamps: a radar whose clock jumps back every frame.
    feed = Feed()
    feed.run(2_500_000)
    feed.break_radar = lambda t: RadarFrame(stamp=Stamp(1_000_000 - t // 1000), sensor_id="radar_front")
    sig = _only(feed.run(feed.now + 200_000), K.SENSOR_OUT_OF_ORDER)
    cases.append((sig.source, sig.kind, sig.level))
    # Rate drop: radar at 5 Hz instead of 20 Hz.
    feed = Feed()
    feed.run(2_500_000)
    feed.break_radar = lambda t: (
        RadarFrame(stamp=Stamp(t - 45_000), sensor_id="radar_front", objects=np.ones((1, 6)) * t)
        if t % 200_000 == 0
        else None
    )
    sigs = feed.run(feed.now + 2_200_000)
    sig = _only(sigs, K.SENSOR_RATE_LOW)
    cases.append((sig.source, sig.kind, sig.level))
    # Blockage: the LiDAR returns almost nothing.
    feed = Feed()
    feed.run(2_500_000)
    feed.lidar_points = 10
    sig = _only(feed.run(feed.now + 100_000), K.SENSOR_BLOCKAGE)
    cases.append((sig.source, sig.kind, sig.level))
    assert cases == [
        ("sensor:imu", K.SENSOR_FROZEN, L.MINIMAL_RISK_MANOEUVRE),
        ("sensor:gnss", K.SENSOR_GARBAGE, L.MINIMAL_RISK_MANOEUVRE),
        ("sensor:radar_front", K.SENSOR_LATENCY, L.SPEED_LIMIT),
        ("sensor:radar_front", K.SENSOR_OUT_OF_ORDER, L.SPEED_LIMIT),
        ("sensor:radar_front", K.SENSOR_RATE_LOW, L.SPEED_LIMIT),
        ("sensor:lidar_top", K.SENSOR_BLOCKAGE, L.MINIMAL_RISK_MANOEUVRE),
    ]


def test_perception_diagnostics_and_weather_map_to_levels() -> None:
    feed = Feed()
    feed.run(2_500_000)
    mon = feed.mon
    mon.observe_diagnostics(
        SensorDiagnostics(
            stamp=Stamp(feed.now), sensor_id="lidar_top", blockage_fraction=0.5, noise_level=0.4
        )
    )
    mon.observe_weather(WeatherReport(stamp=Stamp(feed.now), visibility_m=30.0, precipitation_mmph=20.0))
    sigs = feed.run(feed.now)
    assert _only(sigs, K.SENSOR_BLOCKAGE).level == L.MINIMAL_RISK_MANOEUVRE
    assert _only(sigs, K.SENSOR_NOISE).level == L.SPEED_LIMIT
    assert _only(sigs, K.WEATHER_VISIBILITY).level == L.MINIMAL_RISK_MANOEUVRE
    assert _only(sigs, K.WEATHER_PRECIPITATION).level == L.TAKEOVER_REQUEST
    mon.observe_weather(WeatherReport(stamp=Stamp(feed.now), visibility_m=100.0, precipitation_mmph=6.0))
    sigs = feed.run(feed.now)
    vis = _only(sigs, K.WEATHER_VISIBILITY)
    assert vis.level == L.SPEED_LIMIT and vis.speed_cap_mps == pytest.approx(2.5)
    assert _only(sigs, K.WEATHER_PRECIPITATION).level == L.SPEED_LIMIT


def test_localization_integrity_faults_map_to_levels() -> None:
    feed = Feed()
    feed.run(2_500_000)
    feed.pos_std_m = 0.5
    sig = _only(feed.run(feed.now + 100_000), K.LOCALIZATION_COVARIANCE)
    assert sig.level == L.SPEED_LIMIT and sig.speed_cap_mps == pytest.approx(0.5)  # Snow Lion's forced limit
    feed.pos_std_m = 2.0
    assert _only(feed.run(feed.now + 100_000), K.LOCALIZATION_COVARIANCE).level == L.MINIMAL_RISK_MANOEUVRE
    feed.pos_std_m = 0.05
    feed.valid = False
    assert _only(feed.run(feed.now + 100_000), K.LOCALIZATION_INVALID).level == L.EMERGENCY_STOP
    feed.valid = True
    feed.fix_ok = False
    lost_at = feed.now
    # The receiver's own "no fix" slows the shuttle at once (within a GNSS period + 100 ms)...
    early = _only(feed.run(lost_at + 200_000), K.GNSS_LOST)
    assert early.level == L.SPEED_LIMIT and early.speed_cap_mps is not None
    assert _only(feed.run(lost_at + 1_900_000), K.GNSS_LOST).level == L.SPEED_LIMIT
    # ...and keeps Snow Lion's cap once the fix stays away for gnss_lost_us (no bare takeover request
    # without a cap: the stop comes from the protection level against the lane margin).
    sig = _only(feed.run(lost_at + 2_200_000), K.GNSS_LOST)
    assert sig.level == L.SPEED_LIMIT and sig.speed_cap_mps == pytest.approx(0.5)
    assert "no GNSS fix for 2.2 s" in sig.reason
    for i, total in enumerate((0, 1, 2, 3, 5)):
        feed.mon.observe_gate_rejections(feed.now + i, total)
    assert _only(feed.run(feed.now), K.LOCALIZATION_GATE_REJECTIONS).level == L.SPEED_LIMIT


def test_leaving_the_map_and_the_route(straight_map: HDMap) -> None:
    feed = Feed(straight_map)
    feed.run(2_500_000)
    feed.y_m = -6.5  # beside the bay-less part of the road: off every drivable lanelet
    sigs = feed.run(feed.now + 100_000)
    assert _only(sigs, K.OFF_MAP).level == L.EMERGENCY_STOP
    assert _only(sigs, K.OFF_ROUTE).level == L.MINIMAL_RISK_MANOEUVRE


def _cap(signals: tuple[MalfunctionSignal, ...]) -> float | None:
    return _only(signals, K.LOCALIZATION_DEAD_RECKONING).speed_cap_mps


def test_dead_reckoning_holds_snow_lions_cap_and_never_lets_a_stopped_vehicle_go_again() -> None:
    feed = Feed()
    feed.run(2_500_000)
    assert not [s for s in feed.run(feed.now) if s.kind == K.LOCALIZATION_DEAD_RECKONING]
    feed.source = PositionSource.DEAD_RECKONING
    sig = _only(feed.run(feed.now + 100_000), K.LOCALIZATION_DEAD_RECKONING)
    assert sig.level == L.SPEED_LIMIT and sig.speed_cap_mps == pytest.approx(0.5)
    feed.speed_mps = 0.2  # slowed for something: still Snow Lion's cap
    assert _cap(feed.run(feed.now + 100_000)) == pytest.approx(0.5)
    feed.speed_mps = 0.0
    assert _cap(feed.run(feed.now + 100_000)) == 0.0
    feed.speed_mps = 0.3  # creeping off again, still on dead reckoning: held at standstill
    sig = _only(feed.run(feed.now + 100_000), K.LOCALIZATION_DEAD_RECKONING)
    assert sig.speed_cap_mps == 0.0 and "held at standstill" in sig.reason
    feed.source = PositionSource.GNSS  # a fix holds the pose again: the hold ends
    assert not [s for s in feed.run(feed.now + 100_000) if s.kind == K.LOCALIZATION_DEAD_RECKONING]
    feed.source = PositionSource.DEAD_RECKONING  # a new outage: moving again under the cap
    feed.speed_mps = 3.0
    assert _cap(feed.run(feed.now + 100_000)) == pytest.approx(0.5)


def test_a_protection_level_beyond_the_lane_margin_is_the_manoeuvre_to_a_stop() -> None:
    feed = Feed(config=ReliabilityConfig(sensors=_specs(), lane_margin_m=0.75))
    feed.run(2_500_000)
    feed.pos_std_m = 0.35  # 1.96 sigma = 0.69 m, inside the margin: Snow Lion's cap only
    sig = _only(feed.run(feed.now + 100_000), K.LOCALIZATION_COVARIANCE)
    assert sig.level == L.SPEED_LIMIT
    feed.pos_std_m = 0.40  # 0.78 m > 0.75 m
    sig = _only(feed.run(feed.now + 100_000), K.LOCALIZATION_COVARIANCE)
    assert sig.level == L.MINIMAL_RISK_MANOEUVRE and "lane margin 0.75 m" in sig.reason


def test_the_lane_margin_along_the_route_overrides_the_configured_one() -> None:
    seen: list[float] = []

    def narrow(s_m: float) -> float:
        seen.append(s_m)
        return 0.2

    feed = Feed(config=ReliabilityConfig(sensors=_specs(), lane_margin_m=0.75), lane_margin_m=narrow)
    feed.run(2_500_000)
    feed.pos_std_m = 0.15  # 0.29 m: beyond a 0.2 m margin, far inside 0.75 m
    sig = _only(feed.run(feed.now + 100_000), K.LOCALIZATION_COVARIANCE)
    assert sig.level == L.MINIMAL_RISK_MANOEUVRE and "lane margin 0.20 m" in sig.reason
    assert seen and seen[-1] == pytest.approx(50.0, abs=0.1)  # asked at the pose's route s


def test_without_gnss_a_pose_held_by_landmarks_is_not_capped() -> None:
    feed = Feed()
    feed.run(2_500_000)
    feed.fix_ok = False
    feed.source = PositionSource.LANDMARKS
    sig = _only(feed.run(feed.now + 3_000_000), K.GNSS_LOST)
    assert sig.level == L.NONE and sig.speed_cap_mps is None and "landmarks" in sig.reason
