"""Faults a payload alone cannot show: a blind radar (no clutter), frozen odometry at standstill (alive
counter) and one gross GNSS jump (20 sigma off the EKF), each caught at its first frame."""

from __future__ import annotations

import numpy as np

from lastmile.core.safety_messages import FailSafeLevel, MalfunctionKind
from lastmile.core.sensor_frames import GnssInsFrame, LidarSweep, RadarFrame, WheelOdometryFrame
from lastmile.core.stamp import Stamp
from lastmile.localization.ekf import PoseEkf
from lastmile.safety.reliability_config import ReliabilityConfig, SensorSpec, default_sensor_specs
from lastmile.safety.reliability_monitor import ReliabilityMonitor

K, L = MalfunctionKind, FailSafeLevel


def _radar_monitor() -> ReliabilityMonitor:
    specs = tuple(s for s in default_sensor_specs(radar_keys=("front", "rear")) if s.key == "front")
    return ReliabilityMonitor(ReliabilityConfig(sensors=specs))


def _radar(t_us: int, cycle: int, raw: int) -> RadarFrame:
    return RadarFrame(
        stamp=Stamp(t_us - 60_000),
        sensor_id="front",
        objects=np.zeros((0, 6)),
        cycle=cycle,
        raw_detections=raw,
    )


def test_empty_road_with_clutter_is_fine_but_a_radar_without_any_reflection_is_blocked() -> None:
    mon = _radar_monitor()
    for k in range(40):  # an empty road: no objects, the usual clutter
        mon.observe_frame(k * 50_000, _radar(k * 50_000, k, raw=35))
    assert [s for s in mon.evaluate(40 * 50_000 - 40_000) if s.kind == K.SENSOR_BLOCKAGE] == []
    mon.observe_frame(40 * 50_000, _radar(40 * 50_000, 40, raw=0))
    blocked = [s for s in mon.evaluate(40 * 50_000) if s.kind == K.SENSOR_BLOCKAGE]
    assert len(blocked) == 1 and blocked[0].level == L.MINIMAL_RISK_MANOEUVRE
    assert blocked[0].source == "sensor:front"


def test_radar_that_does_not_report_its_reflections_is_not_judged_blocked() -> None:
    mon = _radar_monitor()
    for k in range(10):
        mon.observe_frame(k * 50_000, _radar(k * 50_000, k, raw=-1))
    assert [s for s in mon.evaluate(9 * 50_000) if s.kind == K.SENSOR_BLOCKAGE] == []


def _odom(t_us: int, cycle: int) -> WheelOdometryFrame:
    return WheelOdometryFrame(
        stamp=Stamp(t_us - 8_000), speed_mps=0.0, steer_front_rad=0.0, steer_rear_rad=0.0, cycle=cycle
    )


def test_frozen_odometry_at_standstill_is_caught_by_its_alive_counter_within_one_period() -> None:
    specs = tuple(s for s in default_sensor_specs() if s.key == "odom")
    mon = ReliabilityMonitor(ReliabilityConfig(sensors=specs))
    t = 0
    for k in range(100):  # parked: the speed repeats, the counter does not
        t = k * 20_000
        mon.observe_frame(t, _odom(t, k % 16))
        assert [s for s in mon.evaluate(t) if s.kind == K.SENSOR_FROZEN] == []
    frozen_from = t + 20_000
    mon.observe_frame(frozen_from, _odom(frozen_from, 99 % 16))  # the gateway repeats its last frame
    frozen = [s for s in mon.evaluate(frozen_from) if s.kind == K.SENSOR_FROZEN]
    assert len(frozen) == 1 and frozen[0].level == L.MINIMAL_RISK_MANOEUVRE


def _fix(t_us: int, x_m: float) -> GnssInsFrame:
    return GnssInsFrame(
        stamp=Stamp(t_us),
        x_m=x_m,
        y_m=0.0,
        yaw_rad=0.0,
        speed_mps=0.0,
        pos_std_m=0.02,
        yaw_std_rad=0.004,
        fix_ok=True,
    )


def test_one_gnss_fix_20_sigma_off_is_a_localization_fault_at_once_while_one_marginal_one_is_not() -> None:
    ekf = PoseEkf()
    mon = ReliabilityMonitor(ReliabilityConfig(sensors=()))
    rng = np.random.default_rng(3)
    for k in range(50):
        t = k * 100_000
        ekf.update_gnss(_fix(t, 10.0 + float(rng.normal(0.0, 0.02))))
        mon.observe_gate_rejections(t, ekf.rejected_fixes, ekf.gross_rejections)
    assert ekf.gross_rejections == 0
    assert [s for s in mon.evaluate(49 * 100_000) if s.kind == K.LOCALIZATION_GATE_REJECTIONS] == []
    t = 50 * 100_000
    ekf.update_gnss(_fix(t, 14.0))  # multipath: 4 m off with the usual 2 cm standard deviation
    mon.observe_gate_rejections(t, ekf.rejected_fixes, ekf.gross_rejections)
    assert ekf.rejected_fixes >= 1 and ekf.gross_rejections == 1
    found = [s for s in mon.evaluate(t) if s.kind == K.LOCALIZATION_GATE_REJECTIONS]
    assert len(found) == 1 and found[0].level == L.SPEED_LIMIT


def _lidar_monitor() -> ReliabilityMonitor:
    return ReliabilityMonitor(
        ReliabilityConfig(sensors=(SensorSpec(key="lidar_top", rate_hz=10.0, frozen_after=3),))
    )


def test_a_lidar_repeating_its_sweep_byte_for_byte_is_frozen_but_one_differing_in_its_last_byte_is_not() -> (
    None
):
    pts = np.random.default_rng(0).normal(size=(5000, 6)).astype(np.float32)
    last = pts.copy()
    last[-1, -1] = np.nextafter(last[-1, -1], np.float32(np.inf))

    def frozen(second: np.ndarray) -> bool:
        mon = _lidar_monitor()
        for k in range(6):
            cloud = pts if k % 2 == 0 else second  # a new sweep (its own copy of the points) every frame
            mon.observe_frame(
                k * 100_000, LidarSweep(stamp=Stamp(k * 100_000 - 50_000), sensor_id="top", points=cloud)
            )
        return any(s.kind == K.SENSOR_FROZEN for s in mon.evaluate(5 * 100_000))

    assert frozen(pts.copy())
    assert not frozen(last)
