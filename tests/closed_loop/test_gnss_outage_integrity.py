"""A long GNSS outage on the campus loop: Snow Lion's cap at once, never a re-acceleration on dead
reckoning, and a minimal-risk stop once the position's protection level exceeds the lane margin."""

import dataclasses

from lastmile.core.safety_messages import FailSafeLevel
from lastmile.core.vehicle_messages import PositionSource
from lastmile.sim.gnss_scenario import GnssOutage, GnssScenario
from lastmile.sim.scenario import default_service

from .harness import steps

OUTAGE_AT_S = 10.0


def test_a_long_outage_slows_to_the_cap_never_reaccelerates_and_stops_beyond_the_lane_margin():
    scenario = dataclasses.replace(
        default_service(seed=0, minutes=1.2),
        gnss=GnssScenario(outages=(GnssOutage(start_s=OUTAGE_AT_S, duration_s=120.0),)),
    )
    speed_at_outage = None
    lowest = None
    capped_at_s = mrm_at_s = stopped_at_s = None
    levels_before_mrm: set[FailSafeLevel] = set()
    sources: set[PositionSource] = set()
    for st in steps(scenario):
        v, d = st.sim.ego_state.speed_mps, st.verdict.directive
        if st.t_s < OUTAGE_AT_S:
            speed_at_outage = v
            continue
        est = st.out.diagnostics.estimate
        if est is not None:
            sources.add(est.source)
        if capped_at_s is None and d.speed_cap_mps is not None and d.speed_cap_mps <= 0.5:
            capped_at_s = st.t_s
        # Never speeds up on dead reckoning: at most the monitor's noise margin (0.1 m/s) and the speed
        # controller's ripple above the lowest speed so far.
        lowest = v if lowest is None else min(lowest, v)
        assert v <= lowest + 0.15, (
            f"re-accelerated on dead reckoning at {st.t_s:.2f} s: {lowest:.2f} -> {v:.2f}"
        )
        if mrm_at_s is None:
            if d.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE:
                mrm_at_s = st.t_s
                assert any("lane margin" in r for r in d.reasons), d.reasons
            else:
                levels_before_mrm.add(d.level)
        elif stopped_at_s is None and v < 0.01:
            stopped_at_s = st.t_s
        elif stopped_at_s is not None:
            assert d.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE  # held: no creeping off on dead reckoning
            if st.t_s > stopped_at_s + 3.0:
                break
    assert speed_at_outage is not None and speed_at_outage > 4.0  # it was cruising when the fix went
    assert capped_at_s is not None and capped_at_s - OUTAGE_AT_S < 0.5  # the receiver's "no fix"
    assert levels_before_mrm <= {FailSafeLevel.NONE, FailSafeLevel.SPEED_LIMIT}  # no bare takeover request
    assert PositionSource.DEAD_RECKONING in sources
    assert mrm_at_s is not None and stopped_at_s is not None, "no minimal-risk stop during the outage"
    assert stopped_at_s - mrm_at_s < 2.0  # from the 0.5 m/s cap at 1 m/s^2
