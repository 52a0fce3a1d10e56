"""Each localization mode says what holds its position: GNSS, landmarks, or nothing (dead reckoning)."""

import dataclasses
import math

import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.stamp import stamp_from_s
from lastmile.core.vehicle_messages import PositionSource
from lastmile.localization.odometry_ekf import OdometryEkf, OdometryEkfConfig
from lastmile.localization.position_source import AbsoluteUpdates

V = 3.0


def _fix(t: float, ok: bool = True, x_off_m: float = 0.0) -> GnssInsFrame:
    return GnssInsFrame(
        stamp=stamp_from_s(t),
        x_m=V * t + x_off_m,
        y_m=0.0,
        yaw_rad=0.0,
        speed_mps=V,
        pos_std_m=0.02,
        yaw_std_rad=0.004,
        fix_ok=ok,
    )


def _drive(ekf: OdometryEkf, seconds: float, outage: tuple[float, float], x_off_m: float = 0.0) -> dict:
    sources = {}
    for k in range(int(seconds * 50)):
        t = k * 0.02
        ekf.predict(stamp_from_s(t), V, 0.0)
        if k % 5 == 0:
            out = outage[0] <= t < outage[1]
            ekf.update_gnss(_fix(t, ok=not out, x_off_m=x_off_m if t >= outage[0] else 0.0))
        sources[round(t, 2)] = ekf.estimate(stamp_from_s(t)).source
    return sources


def test_the_odometry_ekf_is_dead_reckoning_a_second_after_its_last_accepted_fix_and_gnss_at_the_next():
    src = _drive(OdometryEkf(OdometryEkfConfig(zero_slip_offset_m=0.0)), 8.0, (3.0, 6.0))
    assert src[2.9] is PositionSource.GNSS
    assert src[3.8] is PositionSource.GNSS  # last fix at 2.9 s: within the 1 s timeout
    assert src[4.0] is PositionSource.DEAD_RECKONING
    assert src[5.9] is PositionSource.DEAD_RECKONING
    assert src[6.0] is PositionSource.GNSS and src[7.98] is PositionSource.GNSS


def test_fixes_the_gate_rejects_do_not_hold_the_position():
    # After the outage every fix is 8 m off: rejected by the gate, so the estimate stays dead reckoning
    # (until the consistent offset forces a reset, 30 fixes = 3 s later).
    src = _drive(OdometryEkf(OdometryEkfConfig(zero_slip_offset_m=0.0)), 8.0, (3.0, 4.0), x_off_m=8.0)
    assert src[5.0] is PositionSource.DEAD_RECKONING and src[6.5] is PositionSource.DEAD_RECKONING


def test_current_landmarks_hold_the_pose_before_a_newer_fix_and_lapse_to_gnss_then_dead_reckoning():
    # Both at 10 Hz: a fix newer than the last landmark update must not make the pose depend on the
    # receiver (its loss would then read as the loss of the position).
    upd = AbsoluteUpdates(timeout_s=1.0)
    upd.note(PositionSource.LANDMARKS, 1_000_000)
    upd.note(PositionSource.GNSS, 1_050_000)
    assert upd.source_at(1_060_000) is PositionSource.LANDMARKS
    assert upd.source_at(2_020_000) is PositionSource.GNSS  # landmarks lapsed, the fix still holds
    assert upd.source_at(2_060_000) is PositionSource.DEAD_RECKONING


def test_a_source_holds_the_pose_only_within_the_timeout():
    upd = AbsoluteUpdates(timeout_s=1.0)
    assert upd.source_at(0) is PositionSource.DEAD_RECKONING
    upd.note(PositionSource.GNSS, 1_000_000)
    upd.note(PositionSource.LANDMARKS, 1_500_000)
    assert upd.source_at(2_000_000) is PositionSource.LANDMARKS
    assert upd.source_at(2_600_000) is PositionSource.DEAD_RECKONING
    upd.note(PositionSource.GNSS, 2_700_000)
    assert upd.source_at(2_800_000) is PositionSource.GNSS
    with pytest.raises(ConfigError, match="expected a positive number"):
        AbsoluteUpdates(timeout_s=math.inf)


def test_a_float_fix_counts_at_least_its_datasheet_accuracy_whatever_the_receiver_reports():
    from lastmile.core.gnss_messages import GnssQuality

    ekf = OdometryEkf(OdometryEkfConfig(zero_slip_offset_m=0.0))
    ekf.predict(stamp_from_s(0.0), 0.0, 0.0)
    optimistic = dataclasses.replace(_fix(0.02), pos_std_m=0.05, quality=GnssQuality.RTK_FLOAT)
    assert ekf.update_gnss(optimistic)
    assert ekf.estimate(stamp_from_s(0.02)).pos_std_m == pytest.approx(0.2, rel=0.02)  # RTKLIB: float 0.2 m
    rtk = OdometryEkf(OdometryEkfConfig(zero_slip_offset_m=0.0))
    rtk.predict(stamp_from_s(0.0), 0.0, 0.0)
    assert rtk.update_gnss(_fix(0.02))  # reported 0.02 m, above the RTK floor: taken as reported
    assert rtk.estimate(stamp_from_s(0.02)).pos_std_m == pytest.approx(0.02, rel=0.02)
