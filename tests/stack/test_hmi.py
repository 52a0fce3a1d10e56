"""The HMI composer: which behaviour the shuttle announces, on which screens, with which light."""

from __future__ import annotations

import pytest

from lastmile.core.errors import MessageError
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, HmiMessage
from lastmile.stack.hmi import CUES, HmiComposer, cue_for


def _decision(
    state: BehaviourState, reason: str = "cruise", stop_at: float | None = None
) -> BehaviourDecision:
    return BehaviourDecision(
        stamp=Stamp(0),
        state=state,
        speed_limit_mps=5.0,
        stop_at_s_m=stop_at,
        pullover_spot=None,
        merge_from_s_m=None,
        door_open=False,
        risk_track_id=-1,
        reason=reason,
    )


@pytest.mark.parametrize(
    ("state", "reason", "stop_at", "cue"),
    [
        (BehaviourState.NORMAL_DRIVING, "cruise", None, "driving"),
        (BehaviourState.NORMAL_DRIVING, "cruise; stop for crosswalk", 120.0, "yielding_pedestrian"),
        (BehaviourState.NORMAL_DRIVING, "cruise; stop for pedestrian", 120.0, "yielding_pedestrian"),
        (BehaviourState.NORMAL_DRIVING, "cruise; stop for car", 120.0, "driving"),  # following a lead
        (BehaviourState.PULLOVER, "stop S2 requested", 500.0, "pulling_over"),
        (BehaviourState.ONBOARDING, "dwell", 500.0, "doors_open"),
        (BehaviourState.MERGING, "merging", None, "departing"),
        (BehaviourState.INTERSECTION, "full stop", 80.0, "intersection"),
        (BehaviourState.EMERGENCY_STOP, "emergency stop", 10.0, "emergency_stop"),
    ],
)
def test_each_behaviour_is_announced_with_its_cue(
    state: BehaviourState, reason: str, stop_at: float | None, cue: str
) -> None:
    assert cue_for(_decision(state, reason, stop_at), takeover_request=False) == cue


def test_takeover_request_outranks_the_emergency_stop() -> None:
    assert cue_for(_decision(BehaviourState.EMERGENCY_STOP), takeover_request=True) == "takeover_requested"
    assert cue_for(None, takeover_request=True) == "takeover_requested"


def test_composer_emits_every_screen_once_per_change_with_the_light() -> None:
    hmi = HmiComposer()
    first = hmi.step(Stamp(0), _decision(BehaviourState.PULLOVER), False)
    assert [m.screen for m in first] == ["front", "rear", "inside"]
    assert {m.light for m in first} == {"amber"} and {m.cue for m in first} == {"pulling_over"}
    assert first[0].sound == CUES["pulling_over"].sound and first[1].sound == first[2].sound == ""
    for m in first:
        m.validate()
    assert hmi.step(Stamp(100_000), _decision(BehaviourState.PULLOVER), False) == ()
    estop = hmi.step(Stamp(200_000), _decision(BehaviourState.EMERGENCY_STOP), False)
    assert estop[0].light == "red" and estop[0].sound == "alarm"
    takeover = hmi.step(Stamp(300_000), _decision(BehaviourState.EMERGENCY_STOP), True)
    assert takeover[2].text == CUES["takeover_requested"].inside and takeover[0].light == "red_flashing"


def test_hmi_message_rejects_an_unknown_screen_or_light() -> None:
    with pytest.raises(MessageError, match="screen"):
        HmiMessage(stamp=Stamp(0), screen="roof", text="x").validate()
    with pytest.raises(MessageError, match="light"):
        HmiMessage(stamp=Stamp(0), screen="front", text="x", light="purple").validate()


def test_a_drop_off_pull_over_tells_the_passengers_it_is_theirs() -> None:
    import dataclasses

    from lastmile.core.vehicle_messages import StopReason

    drop = dataclasses.replace(
        _decision(BehaviourState.PULLOVER, stop_at=400.0), stop_reason=StopReason.DROP_OFF
    )
    assert cue_for(drop, takeover_request=False) == "dropping_off"
    assert CUES["dropping_off"].inside == "Stopping for your drop-off"
