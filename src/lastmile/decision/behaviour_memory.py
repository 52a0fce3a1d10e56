"""What the behaviour state machine keeps between planning cycles, and what one cycle hands its handlers."""

from __future__ import annotations

from dataclasses import dataclass, field

from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import BehaviourState
from lastmile.decision.decision_config import DecisionConfig, DecisionInput
from lastmile.decision.mission import MissionManager
from lastmile.decision.observed_motion import Trail
from lastmile.decision.right_of_way import ArrivalOrder
from lastmile.decision.stop_constraints import StopConstraint
from lastmile.hdmap.layers import SLayerDatabase


@dataclass(frozen=True, slots=True)
class CrosswalkHold:
    """The last crosswalk yield seen.

    Attributes:
        stop_front_s_m: its stop point (front-bumper route s).
        track_id: the track yielded to.
        seen_s: when it was last seen yielding.
        standing: the shuttle stood for it then.
        settled: the track had settled then (not a new unclassified one, ``unknown_settle_s``).
    """

    stop_front_s_m: float
    track_id: int
    seen_s: float
    standing: bool
    settled: bool


@dataclass(slots=True)
class StopVisit:
    """The requested stop being served, from the pull-over through onboarding to the merge.

    Attributes:
        stop_index: row of the stop in ``SLayerDatabase.stops``; None when no stop is being served.
        spot_front_s_m: route s of the front bumper at the chosen pull-over spot.
        spot_committed: the spot no longer moves (it is within ``spot_commit_m``).
        merge_from_s_m: rear-axle route s where the merge (re)started.
        rear_hold_front_s_m: front-bumper route s the merge stops at while rear traffic holds it
            (fixed when the hold begins; None: no hold).
    """

    stop_index: int | None = None
    spot_front_s_m: float | None = None
    spot_committed: bool = False
    merge_from_s_m: float | None = None
    rear_hold_front_s_m: float | None = None


@dataclass(slots=True)
class DropOffVisit:
    """A passenger's unscheduled drop-off being served (``decision.drop_off``).

    Attributes:
        spot_front_s_m: route s of the front bumper at the kerbside spot; None: no spot (yet).
        curb_d_m: route d of the kerb there (right < 0).
        spot_committed: the spot no longer moves (as a stop's: within ``spot_commit_m``).
        deferred_stop_id: no safe place before this stop: the rider gets off there instead.
        halted_since_s: when the shuttle came to a halt at the spot (the paper's wait runs from here).
        clear_since_s: since when no pedestrian track has been near the doorway side (door closed).
        door_open_for_rider: at a stop, the door was seen open (not yet closing) with the request
            pending: the rider could get off there.
    """

    spot_front_s_m: float | None = None
    curb_d_m: float = 0.0
    spot_committed: bool = False
    deferred_stop_id: str | None = None
    halted_since_s: float | None = None
    clear_since_s: float | None = None
    door_open_for_rider: bool = False

    @property
    def active(self) -> bool:
        """Serving a drop-off at the kerb (not deferred to a stop)."""
        return self.spot_front_s_m is not None


@dataclass(slots=True)
class Boarding:
    """The door cycle at a stop (times in seconds of the stack clock)."""

    door_open_since_s: float | None = None
    doorway_clear_since_s: float | None = None
    door_closing: bool = False


@dataclass(slots=True)
class IntersectionVisit:
    """The all-way stop being handled.

    Attributes:
        arrival: arrival order at the current junction (kept, and reset, across visits of the same one).
        line_index: row of the shuttle's stop line in ``SLayerDatabase.stop_lines``.
        stopped_at_line_since_s: when the shuttle first stood at the line.
        go: the shuttle has the right of way and is crossing.
    """

    arrival: ArrivalOrder | None = None
    line_index: int | None = None
    stopped_at_line_since_s: float | None = None
    go: bool = False


@dataclass(slots=True)
class BehaviourMemory:
    """Everything the state machine carries from one cycle to the next.

    Attributes:
        state: the current behaviour state.
        previous_state: the state an emergency stop returns to once released.
        stop, boarding, intersection: the per-state memories above.
        drop_off: the drop-off being served at the kerb (PULLOVER, ONBOARDING, MERGING without a stop).
        emergency_clear_since_s: when the emergency stop's causes were first seen gone, standing.
        transitions: (t_s, from state, to state, why) of every state change.
    """

    state: BehaviourState = BehaviourState.NORMAL_DRIVING
    previous_state: BehaviourState = BehaviourState.NORMAL_DRIVING
    stop: StopVisit = field(default_factory=StopVisit)
    boarding: Boarding = field(default_factory=Boarding)
    intersection: IntersectionVisit = field(default_factory=IntersectionVisit)
    drop_off: DropOffVisit = field(default_factory=DropOffVisit)
    emergency_clear_since_s: float | None = None
    crosswalk_hold: CrosswalkHold | None = None
    """The last crosswalk yield, held a while after it clears (``BehaviourStateMachine._crosswalk_hold``)."""
    track_trails: dict[int, Trail] = field(default_factory=dict)
    """Recent published positions per track (``observed_motion.updated_trails``)."""
    road_user_ids: frozenset[int] = frozenset()
    """Tracks seen classified as a road user while tracked since (``offroad_unknowns.road_user_ids``)."""
    transitions: list[tuple[float, str, str, str]] = field(default_factory=list)

    def enter(self, state: BehaviourState, t_s: float, why: str) -> None:
        """Change state (a no-op when already there); entering EMERGENCY_STOP remembers where from."""
        if state == self.state:
            return
        if state == BehaviourState.EMERGENCY_STOP:
            self.previous_state = self.state
        self.transitions.append((t_s, self.state.value, state.value, why))
        self.state = state

    def finish_stop(self, t_s: float, why: str) -> None:
        """The stop (or the kerbside drop-off) is served (or skipped): forget it and drive on."""
        self.drop_off = DropOffVisit(deferred_stop_id=self.drop_off.deferred_stop_id)
        self.stop.stop_index = None
        self.stop.spot_front_s_m = None
        self.stop.spot_committed = False
        self.stop.merge_from_s_m = None
        self.stop.rear_hold_front_s_m = None
        self.enter(BehaviourState.NORMAL_DRIVING, t_s, why)


@dataclass(frozen=True, slots=True)
class DecisionContext:
    """What the handlers are given once: the route's layers, the shuttle, the mission, the parameters."""

    layers: SLayerDatabase
    geometry: VehicleGeometry
    mission: MissionManager
    config: DecisionConfig
    route: Polyline

    def ahead_m(self, s_m: float, front_s_m: float) -> float:
        """Route distance from the front (``front_s_m``) forward to ``s_m`` (negative: behind)."""
        return self.route.ds_m(front_s_m, s_m)


@dataclass(slots=True)
class Cycle:
    """One planning cycle as the handlers see it.

    Attributes:
        inp: the cycle's input.
        t_s: its stamp in seconds.
        front_s_m: route s of the front bumper.
        obstacles: tracks on the route (``core.route_obstacles``).
        constraints: stop points found so far; handlers add their own.
        speed_cap_mps: the speed cap before the state's own (speed limit, cruise, fail-safe).
        unsettled_ids: unclassified tracks only just tracked (``offroad_unknowns.unsettled_unknown_ids``).
    """

    inp: DecisionInput
    t_s: float
    front_s_m: float
    obstacles: list[RouteObstacle]
    constraints: list[StopConstraint]
    speed_cap_mps: float
    unsettled_ids: frozenset[int] = frozenset()


@dataclass(frozen=True, slots=True)
class Outcome:
    """What a state's handler decides this cycle.

    Attributes:
        speed_cap_mps: the speed cap after the state's own.
        reason: why, for the decision's ``reason``.
        door_open: the door command.
        hold_still: an emergency stop: stand at the front, whatever the constraints say.
        risk_track_id: the track that keeps an emergency stop (-1: none).
    """

    speed_cap_mps: float
    reason: str
    door_open: bool = False
    hold_still: bool = False
    risk_track_id: int = -1
