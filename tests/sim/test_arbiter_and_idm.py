import math

from lastmile.sim.agents import idm_accel_mps2
from lastmile.sim.arbiter import EGO_ID, AllWayStopArbiter


def test_first_to_arrive_goes_first_after_a_full_stop():
    arb = AllWayStopArbiter(min_wait_s=1.0)
    arb.arrive(5, stop_line_id=1, t_s=10.0)
    arb.arrive(EGO_ID, stop_line_id=2, t_s=11.0)
    assert not arb.may_go(5, t_s=10.5)  # not a full stop yet
    assert arb.may_go(5, t_s=11.2)
    assert not arb.may_go(EGO_ID, t_s=12.5)
    assert arb.earlier_than(EGO_ID) == [5]
    arb.enter(5)
    arb.box_occupied_by = {5}
    assert not arb.may_go(EGO_ID, t_s=12.5)  # box still occupied
    arb.box_occupied_by = set()
    assert arb.may_go(EGO_ID, t_s=12.5)


def test_near_simultaneous_arrivals_are_a_tie():
    arb = AllWayStopArbiter()
    arb.arrive(EGO_ID, 1, 10.0)
    arb.arrive(3, 2, 10.1)
    assert arb.earlier_than(EGO_ID) == []
    assert arb.earlier_than(3) == []


def test_idm_free_road_accelerates_and_closes_gap_brakes():
    assert idm_accel_mps2(2.0, 8.0, math.inf, 0.0, 1.2, 2.0, 2.5, 1.5) > 1.0
    assert idm_accel_mps2(8.0, 8.0, 5.0, 0.0, 1.2, 2.0, 2.5, 1.5) < -2.0
    # At the desired speed, far behind a leader at the same speed: roughly no acceleration.
    assert abs(idm_accel_mps2(8.0, 8.0, 200.0, 8.0, 1.2, 2.0, 2.5, 1.5)) < 0.1
