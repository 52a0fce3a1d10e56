import math

import numpy as np
import pytest

from lastmile.core.errors import MessageError
from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.stamp import Stamp
from lastmile.localization.ekf import PoseEkf

R, V = 40.0, 5.0
W = V / R


def _truth(t):
    return R * math.sin(W * t), R - R * math.cos(W * t), W * t


def _fix(t, rng, sigma=0.03, jump=0.0, ok=True):
    x, y, yaw = _truth(t)
    return GnssInsFrame(
        stamp=Stamp(round(t * 1e6)),
        x_m=x + rng.normal(0, sigma) + jump,
        y_m=y + rng.normal(0, sigma),
        yaw_rad=yaw + rng.normal(0, 0.004),
        speed_mps=V,
        pos_std_m=sigma,
        yaw_std_rad=0.004,
        fix_ok=ok,
    )


def _run(seconds, outage=None, jump_at=None):
    rng = np.random.default_rng(1)
    ekf = PoseEkf()
    errors, valid = [], []
    for k in range(int(seconds * 50)):
        t = k * 0.02
        ekf.predict(Stamp(round(t * 1e6)), V + rng.normal(0, 0.02), W + rng.normal(0, 0.003))
        if k % 5 == 0:
            in_outage = outage is not None and outage[0] <= t < outage[1]
            ekf.update_gnss(
                _fix(
                    t,
                    rng,
                    jump=10.0 if jump_at is not None and abs(t - jump_at) < 1e-9 else 0.0,
                    ok=not in_outage,
                )
            )
        est = ekf.estimate(Stamp(round(t * 1e6)))
        x, y, _ = _truth(t)
        errors.append(math.hypot(est.map_from_base.x_m - x, est.map_from_base.y_m - y))
        valid.append(est.valid)
    return ekf, np.array(errors), np.array(valid)


def test_rtk_fixes_and_odometry_keep_the_error_within_centimetres():
    _, err, valid = _run(30.0)
    assert np.sqrt(np.mean(err[50:] ** 2)) < 0.05
    assert valid[1:].all()


def test_a_five_second_outage_drifts_less_than_a_metre_and_stays_valid():
    _, err, valid = _run(20.0, outage=(10.0, 15.0))
    window = err[(10 * 50) : (15 * 50)]
    assert window.max() < 1.0
    assert valid[(10 * 50) : (15 * 50)].all()


def test_a_ten_metre_jump_is_rejected_by_the_gate():
    ekf, err, _ = _run(12.0, jump_at=10.0)
    assert ekf.rejected == 1
    assert err[(10 * 50) :].max() < 0.1


def test_invalid_before_the_first_fix_and_nan_input_rejected():
    ekf = PoseEkf()
    assert not ekf.estimate(Stamp(0)).valid
    with pytest.raises(MessageError, match="finite"):
        ekf.predict(Stamp(0), float("nan"), 0.0)
