"""A long GNSS outage on the campus loop: Snow Lion's cap at once, never a re-acceleration on dead
reckoning, and a minimal-risk stop once the position's protection level exceeds the lane margin."""

from lastmile.core.safety_messages import FailSafeLevel
from lastmile.core.vehicle_messages import PositionSource
from lastmile.sim.gnss_scenario import GnssOutage, GnssScenario
from lastmile.sim.scenario import Scenario

from .harness import steps

OUTAGE_AT_S = 10.0
CAP_MPS = 0.5
RIPPLE_MPS = 0.05  # the speed controller's overshoot settling on a cap


def test_a_long_outage_slows_to_the_cap_never_reaccelerates_and_stops_beyond_the_lane_margin():
    # The loop alone (no road users, no riders): nothing but the lost fix makes the shuttle slow down.
    scenario = Scenario(
        name="gnss_outage",
        minutes=1.2,
        gnss=GnssScenario(outages=(GnssOutage(start_s=OUTAGE_AT_S, duration_s=120.0),)),
    )
    speed_at_outage = previous = None
    capped_at_s = mrm_at_s = stopped_at_s = None
    levels_before_mrm: set[FailSafeLevel] = set()
    sources: set[PositionSource] = set()
    for st in steps(scenario):
        v, d = st.sim.ego_state.speed_mps, st.verdict.directive
        if st.t_s < OUTAGE_AT_S:
            speed_at_outage = previous = v
            continue
        est = st.out.diagnostics.estimate
        if est is not None:
            sources.add(est.source)
        if capped_at_s is None and d.speed_cap_mps is not None and d.speed_cap_mps <= CAP_MPS:
            capped_at_s = st.t_s
        # Never speeds up on dead reckoning: down to the cap without a rise, then never above it.
        assert previous is not None
        if previous > CAP_MPS + RIPPLE_MPS:
            assert v <= previous + 1e-3, f"re-accelerated at {st.t_s:.2f} s: {previous:.2f} -> {v:.2f} m/s"
        else:
            assert v <= CAP_MPS + RIPPLE_MPS, f"above the cap at {st.t_s:.2f} s: {v:.2f} m/s"
        previous = v
        if mrm_at_s is None:
            if d.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE:
                mrm_at_s = st.t_s
                assert any("lane margin" in r for r in d.reasons), d.reasons
            else:
                levels_before_mrm.add(d.level)
        elif stopped_at_s is None and v < 0.01:
            stopped_at_s = st.t_s
        elif stopped_at_s is not None:
            # Held: no creeping off on dead reckoning.
            assert d.level >= FailSafeLevel.MINIMAL_RISK_MANOEUVRE and v < 0.01
            if st.t_s > stopped_at_s + 3.0:
                break
    assert speed_at_outage is not None and speed_at_outage > 4.0  # it was cruising when the fix went
    assert capped_at_s is not None and capped_at_s - OUTAGE_AT_S < 0.5  # the receiver's "no fix"
    assert levels_before_mrm <= {FailSafeLevel.NONE, FailSafeLevel.SPEED_LIMIT}  # no bare takeover request
    assert PositionSource.DEAD_RECKONING in sources
    assert mrm_at_s is not None and stopped_at_s is not None, "no minimal-risk stop during the outage"
    assert stopped_at_s - mrm_at_s < 2.0  # from the 0.5 m/s cap at 1 m/s^2
