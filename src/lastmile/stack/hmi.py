"""The shuttle's HMI: what its screens, speaker and autonomy-state light say, from its behaviour.

GEM (Sec. VII) and Snow Lion tell pedestrians and passengers what the vehicle is about to do: an LED
screen at the front ("after you" when it yields at a crossing), a rear screen for traffic behind
(pulling over, pulling out), the passengers' screen and chimes inside, and a light that shows the
vehicle drives itself. The composer turns each planning cycle's decision and the safety supervisor's
takeover request into a *cue*; when the cue changes it emits one :class:`HmiMessage` per screen (the
sound on the first, the light on all), so the run log and the fleet dashboard see every change once.
"""

from __future__ import annotations

from dataclasses import dataclass

from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, HmiMessage, StopReason


@dataclass(frozen=True, slots=True)
class HmiCue:
    """Texts per screen, a sound and the light colour for one announced behaviour."""

    front: str
    rear: str
    inside: str
    sound: str
    light: str


CUES: dict[str, HmiCue] = {
    "driving": HmiCue("Campus shuttle", "Autonomous shuttle", "Next stop on request", "", "turquoise"),
    "yielding_pedestrian": HmiCue(
        "After you - please cross",
        "Stopping for pedestrians",
        "Giving way to pedestrians",
        "yield_chime",
        "amber",
    ),
    "intersection": HmiCue(
        "Stopping at intersection", "Stopping", "Stopping at the intersection", "", "amber"
    ),
    "pulling_over": HmiCue(
        "Pulling over", "Pulling over - shuttle stopping", "Arriving at the stop", "indicator_right", "amber"
    ),
    "dropping_off": HmiCue(
        "Pulling over",
        "Pulling over - shuttle stopping",
        "Stopping for your drop-off",
        "indicator_right",
        "amber",
    ),
    "doors_open": HmiCue(
        "Boarding", "Passengers boarding", "Doors open - please board", "door_chime", "amber"
    ),
    "departing": HmiCue(
        "Departing", "Pulling out - please wait", "Doors closed - departing", "chime_depart", "turquoise"
    ),
    "emergency_stop": HmiCue("STOP", "Emergency stop", "Emergency stop - please hold on", "alarm", "red"),
    "takeover_requested": HmiCue(
        "STOP", "Vehicle stopping", "Safety driver: take over now", "takeover_alarm", "red_flashing"
    ),
}


def cue_for(decision: BehaviourDecision | None, takeover_request: bool) -> str:
    """The behaviour to announce; the takeover request outranks everything, then the e-stop."""
    if takeover_request:
        return "takeover_requested"
    if decision is None:
        return "driving"
    state = decision.state
    if state == BehaviourState.EMERGENCY_STOP:
        return "emergency_stop"
    if state == BehaviourState.PULLOVER:
        # A passenger's drop-off (the seat's button): the passengers hear it is theirs, not a stop.
        return "dropping_off" if decision.stop_reason == StopReason.DROP_OFF else "pulling_over"
    if state == BehaviourState.ONBOARDING:
        return "doors_open"
    if state == BehaviourState.MERGING:
        return "departing"
    if state == BehaviourState.INTERSECTION:
        return "intersection"
    # Normal driving: the decision's reason names what it stops for ("...; stop for crosswalk"). A lead
    # car is followed rather than announced (its stop point moves with it every cycle).
    reason = decision.reason
    if decision.stop_at_s_m is not None and (
        "stop for crosswalk" in reason or "stop for pedestrian" in reason
    ):
        return "yielding_pedestrian"
    return "driving"


class HmiComposer:
    """Emits the HMI's messages when the announced behaviour changes."""

    def __init__(self) -> None:
        self.cue = ""

    def step(
        self, now: Stamp, decision: BehaviourDecision | None, takeover_request: bool
    ) -> tuple[HmiMessage, ...]:
        cue = cue_for(decision, takeover_request)
        if cue == self.cue:
            return ()
        self.cue = cue
        c = CUES[cue]
        return (
            HmiMessage(stamp=now, screen="front", text=c.front, sound=c.sound, light=c.light, cue=cue),
            HmiMessage(stamp=now, screen="rear", text=c.rear, light=c.light, cue=cue),
            HmiMessage(stamp=now, screen="inside", text=c.inside, light=c.light, cue=cue),
        )
