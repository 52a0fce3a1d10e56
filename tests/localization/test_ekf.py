import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.gnss_messages import GnssQuality
from lastmile.core.sensor_frames import GnssInsFrame
from lastmile.core.stamp import Stamp, stamp_from_s
from lastmile.localization.ekf import PoseEkf, PoseEkfConfig, _Snap
from lastmile.localization.ekf_model import kalman_update

from .circle_drive import HALF_WHEELBASE, Run, V, W, run_circle
from .circle_drive import all_wheel_steer as _all_wheel_steer
from .circle_drive import fix as _fix
from .circle_drive import unicycle as _unicycle

UNICYCLE = PoseEkfConfig(zero_slip_offset_m=0.0)


def _run(seconds, config=UNICYCLE, **kwargs) -> Run:
    return run_circle(PoseEkf(config), seconds, **kwargs)


def test_rtk_fixes_and_odometry_keep_the_error_within_centimetres():
    run = _run(30.0)
    assert np.sqrt(np.mean(run.err_m[50:] ** 2)) < 0.05
    assert run.valid.all()


def test_a_five_second_outage_with_a_wheel_radius_error_stays_small_because_the_scale_is_learnt():
    # A 0.5 % wheel-radius error: the odometry scale is a state, learnt while fixes arrive.
    run = _run(40.0, outage=(30.0, 35.0), odom_scale=1.005)
    during = run.err_m[(30 * 50) : (35 * 50)]
    assert run.ekf.posterior(stamp_from_s(29.98)).state[6] == pytest.approx(0.005, abs=0.002)
    assert during.max() < 0.2
    assert run.pos_std_m[35 * 50 - 1] > 3 * run.pos_std_m[30 * 50 - 1]  # sigma grows honestly
    assert run.valid[(30 * 50) : (35 * 50)].all()
    assert run.err_m[36 * 50 :].max() < 0.1  # and recovers with the first fixes


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


def test_a_lasting_offset_is_rejected_until_consistent_fixes_reacquire_within_a_second():
    # A persistent 100 m offset (say, the receiver switched datum): the rejected fixes agree with each
    # other to their own reported centimetres, so after reacquire_window_s the filter restarts from them.
    run = _run(15.0, jump_at_s=5.0, jump_m=100.0)
    c = UNICYCLE
    assert run.ekf.resets == 1
    assert c.reacquire_min_fixes <= run.ekf.rejected_fixes <= round(c.reacquire_window_s * 10)  # 10 Hz
    est = run.ekf.estimate(Stamp(15_000_000 - 20_000))
    x, y, _ = _unicycle(15.0 - 0.02)
    assert math.hypot(est.map_from_base.x_m - x - 100.0, est.map_from_base.y_m - y) < 0.1


def test_multipath_jumps_in_changing_directions_never_force_a_reset():
    # Reflections: 4 m jumps whose direction changes every fix. The rejected fixes disagree with each
    # other, so the filter keeps dead reckoning instead of restarting from a wrong fix.
    config = UNICYCLE
    rng = np.random.default_rng(3)
    ekf = PoseEkf(config)
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
    ekf = PoseEkf()
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
    in_order, delivered = PoseEkf(UNICYCLE), PoseEkf(UNICYCLE)
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
        16.0, config=PoseEkfConfig(zero_slip_offset_m=HALF_WHEELBASE), truth=_all_wheel_steer, outage=outage
    )
    naive = _run(16.0, config=UNICYCLE, truth=_all_wheel_steer, outage=outage)
    assert slip_aware.err_m[window].max() < 0.3
    assert naive.err_m[window].max() > 2 * slip_aware.err_m[window].max()


def test_non_finite_or_negative_inputs_raise_message_errors():
    ekf = PoseEkf()
    with pytest.raises(MessageError, match="finite"):
        ekf.predict(Stamp(0), float("nan"), 0.0)
    with pytest.raises(MessageError, match="finite"):
        ekf.predict(Stamp(0), 1.0, float("inf"))
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
        ({"reacquire_min_fixes": 1}, "reacquire_min_fixes"),
        ({"antenna_lever_arm_m": (0.0, float("nan"))}, "antenna_lever_arm_m"),
        ({"gyro_scale_error": -0.01}, "gyro_scale_error"),
    ],
)
def test_bad_configs_are_rejected_with_the_field_named(change, match):
    with pytest.raises(ConfigError, match=match):
        PoseEkfConfig(**change)


# --- the prediction's Jacobian and the update's algebra -------------------------------------------


@st.composite
def snapshots(draw):
    state = np.array(
        (
            draw(st.floats(-100, 100)),
            draw(st.floats(-100, 100)),
            draw(st.floats(-3.1, 3.1)),
            # |v| is not differentiable at 0 (the grade decorrelates with distance travelled).
            draw(st.one_of(st.floats(-8, -0.05), st.floats(0.05, 8))),
            draw(st.floats(-0.02, 0.02)),
            draw(st.floats(-0.5, 0.5)),
            draw(st.floats(-0.03, 0.03)),
            draw(st.floats(-2, 2)),
            draw(st.floats(-2, 2)),
            draw(st.floats(-0.03, 0.03)),
        )
    )
    a = np.array(draw(st.lists(st.floats(-1, 1), min_size=100, max_size=100))).reshape(10, 10)
    cov = a @ a.T + 1e-3 * np.eye(10)
    accel = draw(st.one_of(st.just(math.nan), st.floats(-2, 2)))
    quality = draw(st.sampled_from([None, GnssQuality.RTK_FIXED, GnssQuality.SINGLE]))
    return _Snap(0, True, True, draw(st.floats(-0.5, 0.5)), accel, state, cov, None, quality)


@settings(max_examples=50, deadline=None)
@given(snapshots(), st.floats(0.001, 0.1), st.floats(0.0, 2.0))
def test_prediction_covariance_is_propagated_with_the_numerical_jacobian(snap, dt_s, lever_m):
    ekf = PoseEkf(PoseEkfConfig(zero_slip_offset_m=lever_m))
    t_us = round(dt_s * 1e6)
    out = ekf._propagate(snap, t_us)
    jac = np.zeros((10, 10))
    for j in range(10):
        h = 1e-6
        plus, minus = snap.s.copy(), snap.s.copy()
        plus[j] += h
        minus[j] -= h
        sp = ekf._propagate(snap._replace(s=plus), t_us).s
        sm = ekf._propagate(snap._replace(s=minus), t_us).s
        diff = sp - sm
        diff[2] = (diff[2] + math.pi) % (2 * math.pi) - math.pi
        jac[:, j] = diff / (2 * h)
    q = out.p - jac @ snap.p @ jac.T
    # What is left is the process noise: diagonal and non-negative.
    assert np.allclose(q - np.diag(np.diag(q)), 0.0, atol=1e-6)
    assert (np.diag(q) > -1e-6).all()


@settings(max_examples=50, deadline=None)
@given(snapshots(), st.integers(0, 9), st.floats(-1, 1), st.floats(1e-4, 1.0))
def test_the_update_is_the_kalman_update_and_keeps_the_covariance_positive(snap, index, innov, r):
    h = np.zeros((1, 10))
    h[0, index] = 1.0
    s, p = kalman_update(snap.s, snap.p, h, np.array([innov]), np.array([[r]]))
    gain = snap.p @ h[0] / (h[0] @ snap.p @ h[0] + r)
    assert np.allclose(s, snap.s + gain * innov)
    assert np.allclose(p, (np.eye(10) - np.outer(gain, h[0])) @ snap.p, atol=1e-9)
    assert np.linalg.eigvalsh(p).min() > -1e-9


def test_the_estimate_uses_exactly_the_pose_block_of_the_full_prediction():
    run = _run(12.0, outage=(6.0, 12.0))
    for t in (11.98, 12.03, 11.5):
        stamp = stamp_from_s(t)
        est, post = run.ekf.estimate(stamp), run.ekf.posterior(stamp)
        xy = post.covariance[:2, :2]
        assert est.pos_std_m == pytest.approx(math.sqrt(np.linalg.eigvalsh(xy)[-1]), rel=1e-9)
        assert est.yaw_std_rad == pytest.approx(math.sqrt(post.covariance[2, 2]), rel=1e-9)
        assert (est.map_from_base.x_m, est.map_from_base.y_m) == pytest.approx(
            tuple(post.state[:2]), abs=1e-12
        )
