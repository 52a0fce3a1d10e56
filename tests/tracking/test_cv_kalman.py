import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lastmile.tracking import cv_kalman

finite = st.floats(-50.0, 50.0, allow_nan=False)
positive = st.floats(1e-3, 4.0, allow_nan=False)


@st.composite
def tracks(draw):
    """One track: state (1, 4) and a positive-definite per-axis covariance (1, 3)."""
    state = np.array([[draw(finite), draw(finite), draw(finite), draw(finite)]])
    pp, vv = draw(positive), draw(positive)
    rho = draw(st.floats(-0.95, 0.95))
    return state, np.array([[pp, rho * np.sqrt(pp * vv), vv]])


def _dense(cov_row):
    pp, pv, vv = cov_row
    p = np.zeros((4, 4))
    for pos, vel in ((0, 2), (1, 3)):
        p[pos, pos], p[pos, vel], p[vel, pos], p[vel, vel] = pp, pv, pv, vv
    return p


def _dense_predict(x, p, dt, q):
    f = np.eye(4)
    f[0, 2] = f[1, 3] = dt
    a = abs(dt)
    block = q * np.array([[a**3 / 3, dt * a / 2], [dt * a / 2, a]])
    qm = np.zeros((4, 4))
    qm[np.ix_([0, 2], [0, 2])] = block
    qm[np.ix_([1, 3], [1, 3])] = block
    return f @ x, f @ p @ f.T + qm


@settings(max_examples=60, deadline=None)
@given(tracks(), st.floats(-1.0, 1.0), st.floats(0.0, 9.0))
def test_predict_matches_the_dense_4x4_filter(track, dt, q):
    state, cov = track
    x, p = _dense_predict(state[0], _dense(cov[0]), dt, q)
    new_state, new_cov = cv_kalman.predict(state, cov, np.array([dt]), q)
    assert np.allclose(new_state[0], x) and np.allclose(_dense(new_cov[0]), p)


@settings(max_examples=60, deadline=None)
@given(tracks(), st.lists(finite, min_size=4, max_size=4), positive, positive)
def test_update_matches_the_dense_4x4_filter_and_never_grows_the_covariance(track, z, r_pos, r_vel):
    state, cov = track
    p = _dense(cov[0])
    r = np.diag([r_pos, r_pos, r_vel, r_vel])
    k = p @ np.linalg.inv(p + r)
    x_ref = state[0] + k @ (np.array(z) - state[0])
    p_ref = (np.eye(4) - k) @ p
    new_state, new_cov = cv_kalman.update(state, cov, np.array([z]), np.array([r_pos]), r_vel)
    assert np.allclose(new_state[0], x_ref, atol=1e-9)
    assert np.allclose(_dense(new_cov[0]), p_ref, atol=1e-9)
    assert new_cov[0, 0] <= cov[0, 0] + 1e-12 and new_cov[0, 2] <= cov[0, 2] + 1e-12
    assert new_cov[0, 0] * new_cov[0, 2] - new_cov[0, 1] ** 2 > -1e-12


@settings(max_examples=60, deadline=None)
@given(tracks(), st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.0, 9.0))
def test_two_steps_equal_one_and_a_retrodiction_returns_the_mean(track, dt1, dt2, q):
    state, cov = track
    s1, c1 = cv_kalman.predict(state, cov, np.array([dt1]), q)
    s2, c2 = cv_kalman.predict(s1, c1, np.array([dt2]), q)
    s12, c12 = cv_kalman.predict(state, cov, np.array([dt1 + dt2]), q)
    assert np.allclose(s2, s12) and np.allclose(c2, c12)
    back, back_cov = cv_kalman.predict(s1, c1, np.array([-dt1]), q)
    assert np.allclose(back, state)
    assert back_cov[0, 0] >= cov[0, 0] - 1e-9 and back_cov[0, 2] >= cov[0, 2] - 1e-9


@settings(max_examples=60, deadline=None)
@given(tracks(), st.lists(finite, min_size=4, max_size=4), positive, positive)
def test_gate_distance_is_the_dense_mahalanobis_distance(track, z, r_pos, r_vel):
    state, cov = track
    s = _dense(cov[0]) + np.diag([r_pos, r_pos, r_vel, r_vel])
    nu = np.array(z) - state[0]
    d2, nll, dist2 = cv_kalman.gate_costs(state, cov, np.array([z]), np.array([r_pos]), r_vel)
    assert np.isclose(d2[0, 0], nu @ np.linalg.solve(s, nu), rtol=1e-6, atol=1e-9)
    assert np.isclose(nll[0, 0], d2[0, 0] + np.log(np.linalg.det(s)), rtol=1e-6, atol=1e-6)
    assert np.isclose(dist2[0, 0], nu[0] ** 2 + nu[1] ** 2)
