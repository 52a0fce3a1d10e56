import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.stamp import Stamp, stamp_from_s
from lastmile.localization.odometry_ekf import OdometryEkf, OdometryEkfConfig, zero_slip_offset_m

from .circle_drive import HALF_WHEELBASE, R, Run, V, W, run_circle
from .circle_drive import all_wheel_steer as _all_wheel_steer
from .circle_drive import fix as _fix
from .circle_drive import unicycle as _unicycle

UNICYCLE = OdometryEkfConfig(zero_slip_offset_m=0.0)


def _run(seconds, config=UNICYCLE, **kwargs) -> Run:
    return run_circle(OdometryEkf(config), seconds, **kwargs)


def test_rtk_fixes_and_odometry_keep_the_error_within_centimetres():
    run = _run(30.0)
    assert np.sqrt(np.mean(run.err_m[50:] ** 2)) < 0.05
    assert run.valid.all()


def test_a_five_second_outage_drifts_less_than_a_metre_and_stays_valid_while_sigma_is_small():
    # A 0.5 % wheel-radius error is what dead reckoning cannot see without GNSS.
    run = _run(20.0, outage=(10.0, 15.0), odom_scale=1.005)
    before = run.err_m[(9 * 50) : (10 * 50)]
    during = run.err_m[(10 * 50) : (15 * 50)]
    assert during.max() < 1.0 and during.max() > 2 * before.max()  # it grows, but not far
    assert run.pos_std_m[15 * 50 - 1] > 3 * run.pos_std_m[10 * 50 - 1]
    assert run.valid[(10 * 50) : (15 * 50)].all()
    assert run.err_m[16 * 50 :].max() < 0.1  # and recovers with the first fixes


def test_validity_follows_the_position_sigma_through_a_long_outage():
    run = _run(70.0, outage=(5.0, 65.0))
    cfg = UNICYCLE
    assert np.array_equal(run.valid, run.pos_std_m <= cfg.max_pos_std_m)
    assert not run.valid[(64 * 50) : (65 * 50)].any()  # a minute of dead reckoning is not trusted
    assert run.valid[-50:].all()
    assert run.ekf.resets == 0


def test_a_ten_metre_jump_is_rejected_by_the_gate():
    run = _run(12.0, jump_at_s=10.0)
    assert run.ekf.rejected_fixes == 1
    assert run.err_m[(10 * 50) :].max() < 0.1


def test_a_lasting_offset_is_rejected_until_it_forces_a_reset():
    config = OdometryEkfConfig(zero_slip_offset_m=0.0, reset_after_rejections=20)
    # A persistent 100 m offset (say, the receiver switched datum): after 20 rejected fixes the
    # filter concludes it is the one that is wrong and restarts from the receiver.
    run = _run(15.0, config=config, jump_at_s=5.0, jump_m=100.0)
    assert run.ekf.rejected_fixes == 20 and run.ekf.resets == 1
    est = run.ekf.estimate(Stamp(15_000_000 - 20_000))
    x, y, _ = _unicycle(15.0 - 0.02)
    assert math.hypot(est.map_from_base.x_m - x - 100.0, est.map_from_base.y_m - y) < 0.1


def test_multipath_jumps_in_changing_directions_never_force_a_reset():
    # Reflections: 4 m jumps whose direction changes every fix. The rejected fixes disagree with each
    # other, so the filter keeps dead reckoning instead of restarting from a wrong fix.
    config = OdometryEkfConfig(zero_slip_offset_m=0.0, reset_after_rejections=20)
    rng = np.random.default_rng(3)
    ekf = OdometryEkf(config)
    worst = 0.0
    for k in range(15 * 50):
        t = k * 0.02
        ekf.predict(stamp_from_s(t), V + rng.normal(0, 0.02), W + rng.normal(0, 0.003))
        if k % 5 == 0:
            fix = _fix(t, _unicycle, rng)
            if t >= 5.0:
                angle = rng.uniform(-math.pi, math.pi)
                fix = dataclasses.replace(
                    fix, x_m=fix.x_m + 4.0 * math.cos(angle), y_m=fix.y_m + 4.0 * math.sin(angle)
                )
            ekf.update_gnss(fix)
        if t >= 5.0:
            x, y, _ = _unicycle(t)
            est = ekf.estimate(stamp_from_s(t))
            worst = max(worst, math.hypot(est.map_from_base.x_m - x, est.map_from_base.y_m - y))
    assert ekf.rejected_fixes >= 95 and ekf.resets == 0
    assert worst < 1.0  # dead reckoning, not a jump onto a reflected fix


def test_fixes_without_a_solution_are_skipped_and_the_estimate_is_invalid_before_the_first_fix():
    ekf = OdometryEkf()
    assert not ekf.estimate(Stamp(0)).valid
    ekf.predict(Stamp(0), 0.0, 0.0)
    rng = np.random.default_rng(0)
    assert ekf.update_gnss(_fix(0.0, _unicycle, rng, ok=False)) is False
    assert not ekf.estimate(Stamp(0)).valid and not ekf.initialised
    assert ekf.update_gnss(_fix(0.0, _unicycle, rng)) is True
    assert ekf.estimate(Stamp(0)).valid


def test_late_fixes_give_the_same_estimate_as_in_order_processing():
    # GNSS arrives 30 ms after capture, odometry 8 ms: fixes reach the filter after newer odometry.
    rng = np.random.default_rng(2)
    inputs = []
    for k in range(500):
        t = k * 0.02
        inputs.append((t + 0.008, 0, t, (V + rng.normal(0, 0.02), W + rng.normal(0, 0.003))))
        if k % 5 == 0:
            inputs.append((t + 0.030, 1, t, _fix(t, _unicycle, rng)))
    in_order, delivered = OdometryEkf(UNICYCLE), OdometryEkf(UNICYCLE)
    for ekf, key in ((in_order, lambda e: (e[2], e[1])), (delivered, lambda e: (e[0], e[1]))):
        for _, kind, t, payload in sorted(inputs, key=key):
            if kind == 0:
                ekf.predict(stamp_from_s(t), *payload)
            else:
                ekf.update_gnss(payload)
    for ask in (9_980_000, 9_900_000, 10_050_000):
        a, b = in_order.estimate(Stamp(ask)), delivered.estimate(Stamp(ask))
        assert (a.map_from_base.x_m, a.map_from_base.y_m, a.map_from_base.yaw_rad) == pytest.approx(
            (b.map_from_base.x_m, b.map_from_base.y_m, b.map_from_base.yaw_rad), abs=1e-9
        )
        assert a.pos_std_m == pytest.approx(b.pos_std_m, rel=1e-9)
    assert delivered.dropped_inputs == 0


def test_a_fix_older_than_the_history_is_dropped_and_counted():
    run = _run(3.0)
    stale = _fix(3.0 - 0.02 - 1.5, _unicycle, np.random.default_rng(3), jump_m=0.5)
    before = run.ekf.estimate(Stamp(2_980_000))
    assert run.ekf.update_gnss(stale) is False and run.ekf.dropped_inputs == 1
    assert run.ekf.estimate(Stamp(2_980_000)) == before


def test_estimates_for_a_past_stamp_come_from_the_history():
    run = _run(10.0)
    now = 10.0 - 0.02
    past = now - 0.06  # a radar frame's capture time, 60 ms ago
    est = run.ekf.estimate(stamp_from_s(past))
    x, y, yaw = _unicycle(past)
    assert math.hypot(est.map_from_base.x_m - x, est.map_from_base.y_m - y) < 0.05
    assert est.map_from_base.yaw_rad == pytest.approx(yaw, abs=0.01)
    assert est.speed_mps == pytest.approx(V, abs=0.05) and est.yaw_rate_radps == pytest.approx(W, abs=0.01)


def test_the_imu_yaw_rate_bias_is_learnt_and_keeps_outage_drift_small():
    bias = 0.01
    run = _run(60.0, outage=(50.0, 55.0), imu_bias_radps=bias)
    assert run.ekf.yaw_rate_bias_radps == pytest.approx(bias, abs=0.002)
    assert run.err_m[(50 * 50) : (55 * 50)].max() < 0.5


def test_the_side_slip_of_an_all_wheel_steer_rear_axle_is_modelled():
    outage = (10.0, 15.0)
    window = slice(10 * 50, 15 * 50)
    slip_aware = _run(
        16.0,
        config=OdometryEkfConfig(zero_slip_offset_m=HALF_WHEELBASE),
        truth=_all_wheel_steer,
        outage=outage,
    )
    naive = _run(16.0, config=UNICYCLE, truth=_all_wheel_steer, outage=outage)
    assert slip_aware.err_m[window].max() < 0.3
    assert naive.err_m[window].max() > 2 * slip_aware.err_m[window].max()


def test_the_zero_slip_point_follows_the_wheel_angles():
    wheelbase = 2 * HALF_WHEELBASE
    assert zero_slip_offset_m(wheelbase, 0.2, -0.2) == pytest.approx(HALF_WHEELBASE)
    assert zero_slip_offset_m(wheelbase, -0.2, 0.0) == pytest.approx(0.0)
    # Rear wheels at a third of the front angle, opposite: a quarter of the wheelbase.
    tan_f = 0.3
    rear = -math.atan(tan_f / 3)
    assert zero_slip_offset_m(wheelbase, math.atan(tan_f), rear) == pytest.approx(wheelbase / 4)
    assert zero_slip_offset_m(wheelbase, 0.0, 0.0) is None
    assert zero_slip_offset_m(wheelbase, 0.1, 0.1) is None


def test_an_all_wheel_steer_shuttle_with_its_rear_wheels_straight_is_tracked_through_an_outage():
    # At a curb the all-wheel-steer shuttle keeps its rear wheels straight: the rear axle no longer
    # slides outwards. A filter holding the mid-wheelbase zero-slip point moved the estimate outwards
    # at yaw rate x 1.45 m, its fixes were rejected and the shuttle left the road (snow seed 2, bay).
    outage = (10.0, 15.0)
    window = slice(10 * 50, 15 * 50)
    all_wheel = OdometryEkfConfig(zero_slip_offset_m=HALF_WHEELBASE)
    measured = zero_slip_offset_m(2 * HALF_WHEELBASE, math.atan(2 * HALF_WHEELBASE / R), 0.0)
    follows = _run(16.0, config=all_wheel, truth=_unicycle, outage=outage, lever_m=measured)
    held = _run(16.0, config=all_wheel, truth=_unicycle, outage=outage)
    assert follows.err_m[window].max() < 0.3
    assert held.err_m[window].max() > 2 * follows.err_m[window].max()
    assert follows.ekf._latest[2][1] == pytest.approx(0.0)  # held between odometry samples


def test_non_finite_or_negative_inputs_raise_message_errors():
    ekf = OdometryEkf()
    with pytest.raises(MessageError, match="finite"):
        ekf.predict(Stamp(0), float("nan"), 0.0)
    with pytest.raises(MessageError, match="finite"):
        ekf.predict(Stamp(0), 1.0, float("inf"))
    with pytest.raises(MessageError, match="zero_slip_offset_m"):
        ekf.predict(Stamp(0), 1.0, 0.0, float("nan"))
    with pytest.raises(MessageError, match="non-negative"):
        ekf.predict(Stamp(-5), 1.0, 0.0)
    good = _fix(0.0, _unicycle, np.random.default_rng(0))
    for field, value in (("x_m", float("nan")), ("pos_std_m", float("nan")), ("yaw_std_rad", 0.0)):
        bad = GnssInsFrame(**{**{f: getattr(good, f) for f in good.__slots__}, field: value})
        with pytest.raises(MessageError):
            ekf.update_gnss(bad)
    assert not ekf.initialised


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"max_pos_std_m": 0.0}, "max_pos_std_m"),
        ({"gate_chi2": float("inf")}, "gate_chi2"),
        ({"reset_after_rejections": 0}, "reset_after_rejections"),
    ],
)
def test_bad_configs_are_rejected_with_the_field_named(change, match):
    with pytest.raises(ConfigError, match=match):
        OdometryEkfConfig(**change)


# --- the written-out algebra against dense NumPy --------------------------------------------------


def _dense(packed):
    p = np.zeros((5, 5))
    p[np.triu_indices(5)] = packed
    return p + np.triu(p, 1).T


@st.composite
def snapshots(draw):
    state = (
        draw(st.floats(-100, 100)),
        draw(st.floats(-100, 100)),
        draw(st.floats(-3.1, 3.1)),
        draw(st.floats(-8, 8)),
        draw(st.floats(-0.02, 0.02)),
    )
    a = np.array(draw(st.lists(st.floats(-1, 1), min_size=25, max_size=25))).reshape(5, 5)
    cov = a @ a.T + 1e-3 * np.eye(5)
    packed = tuple(cov[np.triu_indices(5)].tolist())
    return (0, True, (draw(st.floats(-0.5, 0.5)), 0.0), state, packed)


@settings(max_examples=50, deadline=None)
@given(snapshots(), st.floats(0.001, 0.1), st.floats(0.0, 2.0))
def test_prediction_is_the_first_order_propagation_with_the_numerical_jacobian(snap, dt_s, lever_m):
    ekf = OdometryEkf()
    snap = (snap[0], snap[1], (snap[2][0], lever_m), snap[3], snap[4])
    t_us = round(dt_s * 1e6)
    out = ekf._propagate(snap, t_us)
    jac = np.zeros((5, 5))
    for j in range(5):
        h = 1e-6
        plus, minus = list(snap[3]), list(snap[3])
        plus[j] += h
        minus[j] -= h
        sp = np.array(ekf._propagate((*snap[:3], tuple(plus), snap[4]), t_us)[3])
        sm = np.array(ekf._propagate((*snap[:3], tuple(minus), snap[4]), t_us)[3])
        diff = sp - sm
        diff[2] = (diff[2] + math.pi) % (2 * math.pi) - math.pi
        jac[:, j] = diff / (2 * h)
    c = ekf.config
    dt = t_us / 1e6
    q = np.diag(
        [
            c.pos_noise_mps**2 * dt,
            c.pos_noise_mps**2 * dt,
            c.yaw_rate_noise_radps**2 * dt,
            c.accel_noise_mps2**2 * dt,
            c.yaw_rate_bias_walk_radps**2 * dt,
        ]
    )
    expected = jac @ _dense(snap[4]) @ jac.T + q
    assert np.allclose(_dense(out[4]), expected, rtol=1e-5, atol=1e-7)


@settings(max_examples=50, deadline=None)
@given(snapshots(), st.integers(0, 4), st.floats(-1, 1), st.floats(1e-4, 1.0))
def test_a_scalar_update_is_the_dense_kalman_update_and_keeps_the_covariance_positive(snap, index, innov, r):
    s, p = OdometryEkf._scalar_update(snap[3], snap[4], index, innov, r)
    cov = _dense(snap[4])
    h = np.zeros(5)
    h[index] = 1.0
    gain = cov @ h / (h @ cov @ h + r)
    assert np.allclose(s, np.array(snap[3]) + gain * innov)
    new = _dense(p)
    assert np.allclose(new, (np.eye(5) - np.outer(gain, h)) @ cov, atol=1e-9)
    assert np.linalg.eigvalsh(new).min() > -1e-9
