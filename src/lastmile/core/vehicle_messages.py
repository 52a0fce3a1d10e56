"""Messages between the stack's modules and out of the stack: pose, route, decisions, commands, status."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from lastmile.core.arrays import frozen_array
from lastmile.core.errors import MessageError
from lastmile.core.geometry import SE2
from lastmile.core.objects import DetectedObjects, TrackedObjects
from lastmile.core.safety_messages import SafetyDirective
from lastmile.core.stamp import Stamp


class PositionSource(Enum):
    """What holds a localization estimate's position to the map."""

    GNSS = "gnss"
    """GNSS fixes accepted within the mode's timeout."""
    LANDMARKS = "landmarks"
    """Map landmarks (GNSS-denied localization) within the timeout."""
    DEAD_RECKONING = "dead_reckoning"
    """Nothing absolute within the timeout (or never): odometry and IMU only; the error grows."""
    SCAN_MATCHING = "scan_matching"
    """LiDAR scans registered to a point-cloud map (GNSS-denied localization) within the timeout.
    (Last, so the run logs' source codes of the older sources keep their values.)"""
    AMCL = "amcl"
    """A particle filter on the 2-D occupancy map (NUS's AMCL) within the timeout."""


@dataclass(frozen=True, slots=True, kw_only=True)
class LocalizationEstimate:
    """Pose of the base (rear axle) in the map frame, with speed and confidence.

    The confidence is the filter's covariance: ``pos_std_m`` is the sigma of its largest horizontal
    axis (so a bound on the lateral error too), ``yaw_std_rad`` the heading's; ``source`` says what last
    corrected the position (dead reckoning: nothing absolute within the mode's timeout).
    """

    stamp: Stamp
    map_from_base: SE2
    speed_mps: float
    yaw_rate_radps: float
    pos_std_m: float
    yaw_std_rad: float
    valid: bool
    source: PositionSource = PositionSource.GNSS


class BehaviourState(Enum):
    """WATonoBus's decision states (Fig. 8)."""

    NORMAL_DRIVING = "normal_driving"
    INTERSECTION = "intersection"
    PULLOVER = "pullover"
    ONBOARDING = "onboarding"
    MERGING = "merging"
    EMERGENCY_STOP = "emergency_stop"


class TurnSignal(Enum):
    """The direction indicators the actuator command switches (issue #20; aUToronto 7.1.1: the
    behaviour layer toggles the indicator lights during lane changes and turns)."""

    OFF = "off"
    LEFT = "left"
    RIGHT = "right"
    HAZARD = "hazard"
    """All four: an emergency stop or a minimal-risk manoeuvre."""


class StopReason(Enum):
    """Why decision asks for a stop point, for consumers that act on the cause (fleet, HMI, reports)."""

    NONE = "none"
    OBSTACLE = "obstacle"
    """A road user or object in the path ahead (followed as a lead while it moves)."""
    CUT_IN = "cut_in"
    """A car the prediction brings into the path ahead."""
    CROSSWALK = "crosswalk"
    """A pedestrian on, or about to step onto, a crosswalk ahead."""
    TRAFFIC_LIGHT = "traffic_light"
    STOP_LINE = "stop_line"
    """An all-way stop's line (arrival order), or a stop sign's (a full stop, then on)."""
    GIVE_WAY = "give_way"
    """A give-way line or a two-way stop's line while traffic with priority leaves no acceptable gap."""
    BUS_STOP = "bus_stop"
    """The pull-over spot of a stop to serve."""
    ONBOARDING = "onboarding"
    DROP_OFF = "drop_off"
    """The kerbside spot of a passenger's unscheduled drop-off (the seat's drop-off button)."""
    REAR_TRAFFIC = "rear_traffic"
    """Waiting at the curb for traffic behind to pass before merging."""
    MINIMAL_RISK_MANOEUVRE = "minimal_risk_manoeuvre"
    """The vehicle safety's minimal risk manoeuvre."""
    EMERGENCY = "emergency"
    """An emergency stop: held where the front is."""
    INFRASTRUCTURE_CROSSING = "infrastructure_crossing"
    """An infrastructure camera reports pedestrians on a crossing ahead (V2I anticipation)."""
    DETECTED_SIGN = "detected_sign"
    """A stop sign GEM's LiDAR detector found ahead (``[stack.gem_sign_stop]``): a full stop, then on."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PassRequest:
    """Decision's order to pass a stationary obstacle blocking the lane on its left (issue #20).

    Route s are in the front bumper's lap (the decision's frame for stop points); d is left positive
    from the route.

    Attributes:
        track_id: the obstacle being passed.
        start_s_m, end_s_m: the obstacle's extent along the route (its rear and front).
        left_d_m: the obstacle's left edge: the planned body keeps its clearance beyond this.
        max_d_m: the farthest left the body's left side may go (the passable lane's far edge).
        lookout_d_m: the offset the rear axle holds inside the lane while waiting, to see past it.
        wait_s_m: where the front waits (the look-out offset is reached by then).
        approved: the pass may be driven; False: wait at the look-out offset, inside the lane.
        committed: the shuttle has begun to move out: the pass is finished even if traffic appears
            (the in-path test still stops for anything on the planned path).
    """

    track_id: int
    start_s_m: float
    end_s_m: float
    left_d_m: float
    max_d_m: float
    lookout_d_m: float = 0.0
    wait_s_m: float = 0.0
    approved: bool = False
    committed: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class BehaviourDecision:
    """What decision making asks of planning and control this cycle.

    Attributes:
        stop_at_s_m: route s at which the front bumper must be stopped, or None to drive on.
        speed_limit_mps: upper bound on speed in this state (merging is slower than normal driving).
        pullover_spot: the chosen pull-over pose (rear axle, map frame) while pulling over/onboarding.
        door_open: whether the door should be open.
        risk_track_id: the highest-risk obstacle the decision reacted to (-1: none).
        reason: a short human-readable reason, logged and shown on the HMI.
        stop_reason: why ``stop_at_s_m`` is set (NONE when it is not).
        pass_request: pass a stationary obstacle by the adjacent lane (None: stay in the lane).
    """

    stamp: Stamp
    state: BehaviourState
    speed_limit_mps: float
    stop_at_s_m: float | None
    pullover_spot: SE2 | None
    merge_from_s_m: float | None
    door_open: bool
    risk_track_id: int
    reason: str
    stop_reason: StopReason = StopReason.NONE
    pass_request: PassRequest | None = None


TRAJECTORY_COLUMNS = ("x_m", "y_m", "yaw_rad", "curvature_1pm", "s_m")


@dataclass(frozen=True, slots=True, kw_only=True)
class Trajectory:
    """The local path to follow (geometry; speed comes from the longitudinal law, within the
    planner's limits below).

    Attributes:
        points: (N, 5) float64, columns :data:`TRAJECTORY_COLUMNS`, ``s_m`` from the path start.
        route_s0_m: route s of the first point (to relate path s to map features).
        speed_limit_mps: the planner's reference speed cap (a scenario's v_r; inf: none of its own).
        stop_at_route_s_m: route s where the front bumper must stop for the planner (a truncated
            reference route, a lane stop at an observation area; None: drive on).
        truncated: Snow Lion's pi_s: the path meets a static obstacle, and the reference route ends
            before it.
    """

    stamp: Stamp
    points: np.ndarray
    route_s0_m: float
    speed_limit_mps: float = math.inf
    stop_at_route_s_m: float | None = None
    truncated: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "points",
            frozen_array(self.points, np.float64, len(TRAJECTORY_COLUMNS), "Trajectory.points"),
        )
        if self.points.shape[0] < 2:
            raise MessageError(f"Trajectory.points: expected at least 2 points, got {self.points.shape[0]}")


@dataclass(frozen=True, slots=True, kw_only=True)
class ActuatorCommand:
    """Command to the drive-by-wire: longitudinal acceleration and wheel angles.

    ``accel_mps2`` > 0 drives, < 0 brakes. ``steer_rear_rad`` is used only with all-wheel steer
    (WATonoBus: rear = -front). ``emergency_brake`` asks for maximum deceleration. ``turn_signal``
    is the indicator lights' state (``decision.turn_signal``).

    ``throttle`` and ``brake`` are pedal positions in [0, 1] for a throttle/brake vehicle (GEM's twist
    controller, ``control.gem_twist_longitudinal``); both None (the default) on an acceleration
    interface. When they are set they drive the vehicle and ``accel_mps2`` is the acceleration they are
    meant to realise (for the log and the safety gate, which rewrites the pedals when it intervenes).
    """

    stamp: Stamp
    accel_mps2: float
    steer_front_rad: float
    steer_rear_rad: float
    door_open: bool = False
    emergency_brake: bool = False
    turn_signal: TurnSignal = TurnSignal.OFF
    throttle: float | None = None
    brake: float | None = None

    def __post_init__(self) -> None:
        for name in ("accel_mps2", "steer_front_rad", "steer_rear_rad"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise MessageError(f"ActuatorCommand.{name}: expected a finite number, got {value}")
        if (self.throttle is None) != (self.brake is None):
            raise MessageError(
                f"ActuatorCommand: expected throttle and brake both set or both None, "
                f"got throttle={self.throttle}, brake={self.brake}"
            )
        for name in ("throttle", "brake"):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and 0.0 <= value <= 1.0):
                raise MessageError(
                    f"ActuatorCommand.{name}: expected a pedal position in [0, 1], got {value}"
                )

    @property
    def has_pedals(self) -> bool:
        """The command drives a throttle/brake vehicle (pedal positions set)."""
        return self.throttle is not None


@dataclass(frozen=True, slots=True, kw_only=True)
class Heartbeat:
    """A module's pulse: healthy or not, and why."""

    stamp: Stamp
    module: str
    healthy: bool
    reason: str = ""
    exception: bool = False
    """The module raised (its call was contained); the health monitor reports MODULE_EXCEPTION."""


@dataclass(frozen=True, slots=True, kw_only=True)
class HmiMessage:
    """Text and sound for passengers and pedestrians (LED screens, speaker, autonomy light).

    Attributes:
        screen: which display shows ``text``: "front" (the LED screen pedestrians see ahead), "rear"
            (the rear screen, for traffic behind) or "inside" (the passengers' screen).
        text: what it shows.
        sound: the speaker's cue with it ("" silent).
        light: the autonomy-state light's colour at the same time ("" unchanged): "turquoise"
            (driving itself), "amber" (yielding, stopping, doors), "red" (emergency stop), "red_flashing"
            (a person must take over).
        cue: the behaviour the HMI announces, e.g. "yielding_pedestrian", "pulling_over", "departing",
            "emergency_stop", "takeover_requested" ("" for none).
    """

    stamp: Stamp
    screen: str
    text: str
    sound: str = ""
    light: str = ""
    cue: str = ""

    def validate(self) -> None:
        if self.screen not in HMI_SCREENS:
            raise MessageError(f"HmiMessage.screen: expected one of {HMI_SCREENS}, got {self.screen!r}")
        if self.light not in HMI_LIGHTS:
            raise MessageError(f"HmiMessage.light: expected one of {HMI_LIGHTS}, got {self.light!r}")


HMI_SCREENS = ("front", "rear", "inside")
HMI_LIGHTS = ("", "turquoise", "amber", "red", "red_flashing")


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleStatus:
    """What the stack reports about itself (to the fleet and the run log)."""

    stamp: Stamp
    map_from_base: SE2 | None
    speed_mps: float
    state: BehaviourState
    route_s_m: float
    door_open: bool
    healthy: bool
    next_stop_id: str = ""


@dataclass(frozen=True, slots=True, kw_only=True)
class StackDiagnostics:
    """What the vehicle software tells the vehicle's safety each tick (the safety runs apart from it).

    Attributes:
        estimate: the localization estimate, on planning cycles (the integrity checks' rate), else None.
        gate_rejections_total: GNSS fixes the localization's innovation gate rejected so far.
        gross_rejections_total: of those, fixes far beyond any plausible error (a single fix 20 sigma off).
        speed_mps: the stack's own speed estimate (localization's while valid, else wheel odometry).
        front_route_s_m: route s of the front bumper, None before the first localized planning cycle.
    """

    stamp: Stamp
    estimate: LocalizationEstimate | None
    gate_rejections_total: int
    gross_rejections_total: int
    speed_mps: float
    front_route_s_m: float | None


LATENCY_HISTOGRAM_EDGES_MS = tuple(float(x) for x in np.logspace(-2, 4, 37))
"""Bins of the per-module latency histograms in :class:`VehicleReport`: 0.01 ms to 10 s, six per decade
(times outside go to the end bins)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleReport:
    """What the vehicle software reports about a whole run (timing and counters, no ground truth).

    Attributes:
        modules: compute time per module: ``p50_ms``, ``p95_ms``, ``max_ms`` and ``calls`` of the
            steady state (None before a second call), ``cpu_p50_ms`` and ``cpu_p95_ms`` (the thread's
            CPU time, steady state), ``warmup_ms`` and ``warmup_cpu_ms`` (the first call, apart: wall
            and CPU time),
            ``budget_ms`` and ``over_budget`` (its cycle budget and the calls over it), and
            ``histogram`` (steady calls per bin of :data:`LATENCY_HISTOGRAM_EDGES_MS`).
        counters: named totals (frames rejected, V2I reports received, perception frame counts...).
        perception: the perception chain's own summary (rig frames, clusters, curb offsets), if any.
    """

    modules: dict[str, dict[str, Any]]
    counters: dict[str, int]
    perception: dict[str, float | int | None] = field(default_factory=dict)


@dataclass(frozen=True, slots=True, kw_only=True)
class SafetyVerdict:
    """What the vehicle's safety (apart from the stack) made of one tick.

    Attributes:
        directive: the fail-safe directive in force (the stack obeys it from its next tick on).
        command: the command sent to the drive-by-wire: the stack's, gated by the directive, or the
            safety's own brake command; None holds the vehicle's default brake.
        watchdog_tripped: the hardware watchdog has cut the stack's command stream (latched).
        stack_failed: the vehicle software raised, or returned no command, on this tick.
    """

    stamp: Stamp
    directive: SafetyDirective
    command: ActuatorCommand | None
    watchdog_tripped: bool = False
    stack_failed: bool = False

    @property
    def takeover_request(self) -> bool:
        return self.directive.takeover_request


@dataclass(frozen=True, slots=True, kw_only=True)
class StackOutput:
    """Everything one stack tick returns.

    Attributes:
        command: the actuator command (the vehicle's safety gates it before the drive-by-wire).
        heartbeats: the modules that ran this tick and how their calls ended (the safety's process
            health monitor watches them).
        diagnostics: what the vehicle's safety needs from the stack each tick.
        stop_reason: the cause of the decision's stop point when one of :class:`StopReason` applies.
        tracks: the tracks decision and planning used, on planning cycles (None otherwise); for the
            black box, never read by the vehicle's safety.
        trajectory: the planned trajectory, on planning cycles that planned (None otherwise); likewise.
        detections: on planning cycles, the detections the tracker consumed since the previous one, map
            frame, one message per frame fused (radar object lists in radar mode, the LiDAR/camera/radar
            late fusion's output with raw sensors); empty when none arrived, None off planning cycles.
            For the black box, never read by the vehicle's safety.
    """

    command: ActuatorCommand | None
    status: VehicleStatus | None = None
    decision: BehaviourDecision | None = None
    hmi: tuple[HmiMessage, ...] = field(default_factory=tuple)
    heartbeats: tuple[Heartbeat, ...] = field(default_factory=tuple)
    diagnostics: StackDiagnostics | None = None
    stop_reason: StopReason = StopReason.NONE
    tracks: TrackedObjects | None = None
    trajectory: Trajectory | None = None
    detections: tuple[DetectedObjects, ...] | None = None
