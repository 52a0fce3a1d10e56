"""Snow Lion's s-t search + OSQP piecewise-jerk speed profile."""

import numpy as np
import pytest

from lastmile.core.errors import MessageError
from lastmile.planning.speed_limits import combined_speed_limit_mps
from lastmile.planning.st_speed import StObstacle, StSpeedConfig, StSpeedPlanner

S = np.arange(0.0, 80.0, 0.5)
FREE = combined_speed_limit_mps(S, np.zeros_like(S), 5.0, 1.0)


def _within_limits(plan, c: StSpeedConfig) -> None:
    assert plan.solved
    assert np.all(plan.a_mps2 <= c.max_accel_mps2 + 1e-3) and np.all(plan.a_mps2 >= -c.max_decel_mps2 - 1e-3)
    assert np.all(np.abs(plan.jerk_mps3) <= c.max_jerk_mps3 + 1e-3)
    assert np.all(np.diff(plan.s_m) >= -1e-6)


def test_free_road_accelerates_to_the_limit_within_accel_and_jerk_limits():
    p = StSpeedPlanner()
    plan = p.plan(S, FREE, 0.0, 0.0)
    _within_limits(plan, p.config)
    assert plan.v_mps[0] == pytest.approx(0.0, abs=1e-6)
    assert plan.v_mps[-1] == pytest.approx(5.0, abs=0.05)
    assert np.all(plan.v_mps <= 5.0 + 1e-3)


def test_stop_point_is_reached_and_not_passed():
    p = StSpeedPlanner()
    lim = combined_speed_limit_mps(S, np.zeros_like(S), 5.0, 1.0, stop_s_m=25.0, max_decel_mps2=1.2)
    plan = p.plan(S, lim, 5.0, 0.0)
    _within_limits(plan, p.config)
    assert plan.s_m.max() <= 25.0 + 0.05
    assert plan.v_mps[-1] == pytest.approx(0.0, abs=0.05)
    assert plan.s_m[-1] > 23.0


def test_yields_to_a_pedestrian_crossing_ahead_and_goes_once_it_has_passed():
    p = StSpeedPlanner()
    ped = StObstacle(t_s=np.array([0.0, 5.0]), s_lo_m=np.array([20.0, 20.0]), s_hi_m=np.array([21.0, 21.0]))
    plan = p.plan(S, FREE, 4.0, 0.0, [ped])
    _within_limits(plan, p.config)
    during = plan.t_s <= 5.0
    assert np.all(plan.s_m[during] <= 20.0 - p.config.follow_gap_m + 0.05)
    assert plan.s_m[-1] > 21.0 + p.config.follow_gap_m  # through after it cleared


def test_passes_before_an_obstacle_that_arrives_late():
    p = StSpeedPlanner()
    # Occupies s 10..11 only from t = 6 s: at 5 m/s the shuttle is long past by then.
    late = StObstacle(t_s=np.array([6.0, 8.0]), s_lo_m=np.array([10.0, 10.0]), s_hi_m=np.array([11.0, 11.0]))
    plan = p.plan(S, FREE, 5.0, 0.0, [late])
    _within_limits(plan, p.config)
    assert plan.s_m[plan.t_s >= 6.0].min() > 11.0 + p.config.follow_gap_m


def test_follows_a_slower_lead_vehicle_at_the_gap():
    p = StSpeedPlanner()
    t = np.linspace(0.0, 8.0, 17)
    lead = StObstacle(t_s=t, s_lo_m=15.0 + 2.0 * t, s_hi_m=19.5 + 2.0 * t)
    plan = p.plan(S, FREE, 5.0, 0.0, [lead])
    _within_limits(plan, p.config)
    assert np.all(plan.s_m <= 15.0 + 2.0 * plan.t_s - p.config.follow_gap_m + 0.05)
    # Converging on the lead's speed, with room to shed the rest: s + tau (v - v_lead) stays behind the gap.
    assert plan.v_mps[-1] == pytest.approx(2.0, abs=0.5)
    tau = p.config.headway_s
    ahead = 15.0 + 2.0 * plan.t_s[1:] - p.config.follow_gap_m
    assert np.all(plan.s_m[1:] + tau * (plan.v_mps[1:] - 2.0) <= ahead + 0.05)


def test_blocked_immediately_gives_a_flagged_full_stop():
    p = StSpeedPlanner()
    wall = StObstacle(t_s=np.array([0.0, 8.0]), s_lo_m=np.array([1.0, 1.0]), s_hi_m=np.array([2.0, 2.0]))
    plan = p.plan(S, FREE, 5.0, 0.0, [wall])
    assert not plan.solved
    assert plan.v_mps[-1] == 0.0 and np.all(np.diff(plan.v_mps) <= 0.0)


def test_workspace_is_reused_and_repeat_calls_give_identical_plans():
    p = StSpeedPlanner()
    a = p.plan(S, FREE, 3.0, 0.0)
    solver = p._solver
    p.plan(S, FREE, 1.0, 0.5)
    b = StSpeedPlanner().plan(S, FREE, 3.0, 0.0)
    assert p._solver is solver
    np.testing.assert_allclose(a.v_mps, b.v_mps, atol=1e-3)


def test_bad_inputs_are_named():
    p = StSpeedPlanner()
    with pytest.raises(MessageError, match="v0 >= 0"):
        p.plan(S, FREE, -1.0, 0.0)
    with pytest.raises(MessageError, match="increasing"):
        p.plan(S[::-1], FREE, 1.0, 0.0)
    bad = StObstacle(t_s=np.array([0.0, 1.0]), s_lo_m=np.array([5.0, 5.0]), s_hi_m=np.array([4.0, 4.0]))
    with pytest.raises(MessageError, match="s_hi_m >= s_lo_m"):
        p.plan(S, FREE, 1.0, 0.0, [bad])


def test_infinite_limits_are_capped_at_the_top_speed():
    p = StSpeedPlanner()
    plan = p.plan(S, np.full(S.shape, np.inf), 5.0, 0.0)
    assert plan.solved and plan.v_mps.max() <= p.config.max_speed_mps + 1e-3


@pytest.mark.parametrize("a0", [0.0, -0.3, 0.5])
def test_a_start_above_the_limit_is_shed_within_the_jerk_limit_not_a_full_stop(a0: float):
    """The cap falls from 5.5 to 3.5 m/s ahead of a bay: the search and the QP shed the overspeed
    (braking reached at the jerk limit) instead of finding no way at all."""
    p = StSpeedPlanner()
    plan = p.plan(S, np.full(S.shape, 3.5), 5.5, a0)
    assert plan.solved
    c = p.config
    assert np.all(np.abs(plan.jerk_mps3) <= c.max_jerk_mps3 + 1e-3)
    assert plan.a_mps2.min() >= -c.max_decel_mps2 - 1e-3
    assert plan.v_mps[-1] <= 3.5 + 1e-3 and plan.v_mps.min() > 2.0
