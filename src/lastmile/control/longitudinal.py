"""WATonoBus's longitudinal law (eqs. 1-3) with a curvature speed limit and a jerk-limited output, and the
registry of longitudinal controllers (with aUToronto's cascaded PI over its trapezoidal profile)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

import numpy as np

from lastmile.control.cascaded_pi import CascadedPiConfig, CascadedPiSpeedController
from lastmile.control.gem_twist_longitudinal import GemTwistLongitudinalController
from lastmile.control.twist_controller import TwistControllerConfig
from lastmile.core.curve_speed import curvature_speed_limit_mps
from lastmile.core.errors import ConfigError
from lastmile.core.vehicle_messages import Trajectory


@dataclass(frozen=True, slots=True, kw_only=True)
class LongitudinalConfig:
    """Parameters of the speed law.

    Attributes:
        nominal_accel_mps2: a_nom of eq. (1), toward the reference speed.
        brake_trigger_mps2: eq. (2) takes over once holding the gap needs at least this deceleration,
            so braking starts early and stays near-constant rather than late and hard. 0.8 m/s^2 was
            faster over the service (+1 % mean speed) but braked too late for a car cutting in ahead
            (a collision at 3.2 m/s), a box on the occupancy grid and a two-way stop's gap.
        max_decel_mps2: the deepest braking the law commands (a stop point that appears late).
        comfort_decel_mps2: braking up to this is comfortable (Snow Lion's envelope: -1.83 m/s^2); a
            stop needing more is urgent, and its braking may ramp in faster than ``max_jerk_mps3``: the
            more it needs, the faster (1x the limit just past this, 2x at ``max_decel_mps2``).
        max_accel_mps2: the largest acceleration commanded (Snow Lion's envelope: 1.12 m/s^2).
        max_lateral_accel_mps2: comfort bound giving the curvature speed limit v = sqrt(a_lat / kappa).
        speed_gain_per_s: proportional gain from speed error to acceleration (the low-level loop).
        rest_gain_per_s: the speed loop's gain once V_des is zero (below 1 / (4 x the drive's ~0.25 s
            lag), so the vehicle settles onto rest without overshooting it).
        max_jerk_mps3: rate limit on the commanded acceleration (Snow Lion's jerk stays within 1.84 m/s^3).
        reference_jerk_mps3: rate limit of the reference acceleration that V_des integrates, below
            ``max_jerk_mps3`` so the speed loop's corrections fit under the command's limit.
        stop_jerk_mps3: the reference deceleration fades out at this jerk as V_des reaches zero
            (|a| <= sqrt(2 j v)), so the vehicle comes to rest with almost no deceleration left: the
            step from the last deceleration to zero when the wheels stop is a jerk a rider feels. The
            drive's ~0.25 s lag leaves about j x 0.25 s of it; 0.5 m/s^3 keeps that step's 10 Hz jerk
            near 1.25 m/s^3.
        hold_speed_mps: below this measured speed, with V_des at zero, the brake is held firmly.
        arrive_m: at rest this close to the stop point counts as there (the fade-out's tail would
            otherwise creep the last centimetres).
        restart_gap_m: at rest short of a stop point, the reference starts again only once the point
            is this far ahead (an obstacle that moved off), not to creep up the last metre.
        overshoot_speed_mps: reaching the stop point faster than this is an overshoot, braked for at
            the urgent rate; slower, the speed loop sheds the rest in proportion to the speed.
        cascaded_pi: parameters of aUToronto's cascaded PI controller (registry name ``cascaded_pi``).
        gem_twist: parameters of GEM's twist controller (registry name ``gem_twist``; its reference is
            this law's V_des). None: its defaults (and the run's configuration echo stays as it was).
    """

    nominal_accel_mps2: float = 0.8
    brake_trigger_mps2: float = 0.6
    max_decel_mps2: float = 3.0
    comfort_decel_mps2: float = 1.8
    max_accel_mps2: float = 1.1
    max_lateral_accel_mps2: float = 1.0
    speed_gain_per_s: float = 1.2
    rest_gain_per_s: float = 0.6
    max_jerk_mps3: float = 1.8
    reference_jerk_mps3: float = 1.5
    stop_jerk_mps3: float = 0.5
    hold_speed_mps: float = 0.005
    overshoot_speed_mps: float = 0.5
    restart_gap_m: float = 3.0
    arrive_m: float = 0.3
    cascaded_pi: CascadedPiConfig = field(default_factory=CascadedPiConfig)
    gem_twist: TwistControllerConfig | None = None

    def __post_init__(self) -> None:
        for name in (
            "nominal_accel_mps2",
            "brake_trigger_mps2",
            "max_decel_mps2",
            "comfort_decel_mps2",
            "max_accel_mps2",
            "max_lateral_accel_mps2",
            "speed_gain_per_s",
            "rest_gain_per_s",
            "max_jerk_mps3",
            "reference_jerk_mps3",
            "stop_jerk_mps3",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"LongitudinalConfig.{name}: expected a positive number, got {value!r}")
        if self.comfort_decel_mps2 > self.max_decel_mps2:
            raise ConfigError(
                "LongitudinalConfig: expected comfort_decel_mps2 <= max_decel_mps2, got "
                f"{self.comfort_decel_mps2} > {self.max_decel_mps2}"
            )


class WatonobusLongitudinalController:
    """Desired speed V_des updated every control step, then tracked by a P loop.

    Eq. (1): V_des(k) = V_des(k-1) + a_nom * dt toward the reference speed.
    Eqs. (2)-(3): with an obstacle (or stop point) Delta s ahead, a_des = -V_des^2 / (2 (Delta s -
    Delta s_min)) and V_des(k) = V_des(k-1) + a_des * dt. The caller passes the stop point already
    shifted by Delta s_min, so here the gap is ``stop_s - front_s``.

    Ours, for comfort (the paper's law steps its acceleration where V_des meets the reference and where
    it reaches zero): the acceleration V_des integrates is itself rate-limited (``reference_jerk_mps3``)
    and aims at the reference speed along an S-curve (|a| <= sqrt(2 j |Delta v|), arriving with zero
    acceleration); toward a stop it fades out as sqrt(2 j_stop V_des), and eq. (2) aims short of the
    stop point by the distance that fade-out adds (D^3 / (6 j_stop^2)). A stop that needs more than
    ``comfort_decel_mps2`` is urgent: its braking ramps in faster than the jerk limit, in proportion to
    how far past comfort it is (twice the limit at ``max_decel_mps2``).
    """

    def __init__(self, config: LongitudinalConfig | None = None) -> None:
        self.config = config or LongitudinalConfig()
        self.v_des_mps = 0.0
        self.a_ref_mps2 = 0.0
        self.accel_cmd_mps2 = 0.0
        self._braking = False
        # Set by a reset: the vehicle has not yet come to rest for the stop point ahead, so the last
        # metre's braking hold does not apply until it has moved off (see ``_stop_accel``).
        self._fresh = False

    def reset(self, speed_mps: float) -> None:
        self.v_des_mps = speed_mps
        self.a_ref_mps2 = 0.0
        self.accel_cmd_mps2 = 0.0
        self._braking = False
        self._fresh = True

    def reference_speed_mps(
        self, trajectory: Trajectory | None, path_s_m: float, speed_cap_mps: float
    ) -> float:
        """The cap lowered wherever a curve ahead needs it, reachable with comfortable braking."""
        if trajectory is None:
            return speed_cap_mps
        pts = trajectory.points
        ahead = pts[:, 4] - path_s_m
        mask = (ahead >= 0.0) & (ahead <= 40.0)
        if not np.any(mask):
            return speed_cap_mps
        v_curve = curvature_speed_limit_mps(pts[mask, 3], self.config.max_lateral_accel_mps2)
        reachable = np.sqrt(v_curve**2 + 2.0 * self.config.nominal_accel_mps2 * ahead[mask])
        return float(min(speed_cap_mps, reachable.min()))

    def step(self, dt_s: float, speed_mps: float, v_ref_mps: float, gap_to_stop_m: float | None) -> float:
        """Commanded acceleration (m/s^2) for this step."""
        c = self.config
        at_rest = speed_mps < c.hold_speed_mps
        if gap_to_stop_m is not None and (gap_to_stop_m <= 0.05 or (at_rest and gap_to_stop_m < c.arrive_m)):
            # At the stop point (or at rest within ``arrive_m`` of it) the reference is at rest; the
            # speed loop sheds what is left in proportion to it (no step), and only a real overshoot
            # brakes at the urgent rate, ramping in as hastily as the deepest braking. Graded by the
            # loop's smaller demand instead, snow seed 0 diverged at an emergency stop and later met an
            # urgent stop out of the envelope (-2.73 m/s^3 at 510.9 s).
            self.v_des_mps = self.a_ref_mps2 = 0.0
            urgent = speed_mps > c.overshoot_speed_mps
            haste = self._haste(c.max_decel_mps2) if urgent else 1.0
        else:
            urgent, haste = self._update_reference(dt_s, v_ref_mps, gap_to_stop_m, speed_mps)
        # With the reference at rest the loop alone brings the vehicle to a stop; a softer gain there
        # keeps that last approach overdamped (with the drive's lag the full gain rings, and the wheels
        # stop while still braking: a step a rider feels).
        gain = c.speed_gain_per_s if self.v_des_mps > 0.0 else c.rest_gain_per_s
        target = self.a_ref_mps2 + gain * (self.v_des_mps - speed_mps)
        if self.v_des_mps == 0.0 and speed_mps < c.hold_speed_mps:
            # Hold the vehicle firmly once stopped, rather than creeping on a tiny positive error.
            target = min(target, -1.0)
        # A stop that is not urgent never asks for more than the comfortable deceleration: the speed
        # loop's correction on top of a reference already near it went past the envelope (snow seed 1,
        # a pedestrian first seen 14 m before the crossing at 5.7 m/s: -1.86 m/s^2 against -1.83). The
        # vehicle then runs a few centimetres long; one that would reach the point faster than
        # ``overshoot_speed_mps`` is urgent, and braked for at up to ``max_decel_mps2``.
        floor = c.max_decel_mps2 if urgent else c.comfort_decel_mps2
        target = min(max(target, -floor), c.max_accel_mps2)
        if at_rest and target > 0.0 and self.accel_cmd_mps2 < 0.0:
            # Moving off from the hold: a brake command on a standing vehicle accelerates nothing, so
            # it is released at once, not ramped out at the jerk limit (from the -1.0 m/s^2 hold at
            # 1.8 m/s^3, 0.56 s standing still after every go; the rider feels the drive's answer,
            # which starts from zero either way).
            self.accel_cmd_mps2 = 0.0
        step = c.max_jerk_mps3 * dt_s
        # An urgent stop may ramp its braking in faster: safety first, comfort second.
        lo = self.accel_cmd_mps2 - haste * step
        hi = self.accel_cmd_mps2 + step
        self.accel_cmd_mps2 = min(max(target, lo), hi)
        return self.accel_cmd_mps2

    def _update_reference(
        self, dt_s: float, v_ref_mps: float, gap_to_stop_m: float | None, speed_mps: float
    ) -> tuple[bool, float]:
        """Advance a_ref and V_des one step (eqs. 1-3, jerk-limited).

        Returns whether the stop is urgent, and how many times the jerk limit its braking may ramp in at.
        """
        c = self.config
        a_target = self._free_accel(v_ref_mps)
        stopping = urgent = False
        haste = 1.0
        if gap_to_stop_m is None:
            self._braking = False
        else:
            stop = self._stop_accel(gap_to_stop_m, speed_mps)
            if stop is not None and stop[0] < a_target:
                a_target, stopping, urgent = stop[0], True, stop[1]
                haste = self._haste(-stop[0]) if urgent else 1.0
        ramp = c.reference_jerk_mps3 * dt_s
        if urgent:
            self.a_ref_mps2 = max(a_target, self.a_ref_mps2 - haste * ramp)
        else:
            self.a_ref_mps2 = min(max(a_target, self.a_ref_mps2 - ramp), self.a_ref_mps2 + ramp)
        v_next = self.v_des_mps + self.a_ref_mps2 * dt_s
        if not stopping and (v_next - v_ref_mps) * (self.v_des_mps - v_ref_mps) <= 0.0:
            # Eased onto the reference: land on it (the residual acceleration is ~2 j dt).
            v_next, self.a_ref_mps2 = v_ref_mps, 0.0
        if v_next <= 0.0:
            v_next, self.a_ref_mps2 = 0.0, 0.0
        self.v_des_mps = v_next
        return urgent, haste

    def _haste(self, decel_mps2: float) -> float:
        """How many times the jerk limit an urgent stop's braking ramps in at: 1 just past the comfortable
        deceleration, rising to 2 at ``max_decel_mps2``. A stop barely past comfort needs no haste, and
        ramping it in at twice the limit broke the jerk envelope for nothing (a crosswalk yield just past
        comfort, snow seed 4 at 507 s with a 0.8 m/s^2 brake trigger: -2.80 m/s^3); one needing the
        deepest braking gets it soonest."""
        c = self.config
        span = c.max_decel_mps2 - c.comfort_decel_mps2
        over = (decel_mps2 - c.comfort_decel_mps2) / span if span > 0.0 else 1.0
        return 1.0 + min(max(over, 0.0), 1.0)

    def _free_accel(self, v_ref_mps: float) -> float:
        """Eq. (1)'s a_nom toward the reference, eased so V_des meets it with zero acceleration."""
        c = self.config
        dv = v_ref_mps - self.v_des_mps
        ease = math.sqrt(2.0 * c.reference_jerk_mps3 * abs(dv))
        return math.copysign(min(c.nominal_accel_mps2, ease), dv)

    def _stop_accel(self, gap_m: float, speed_mps: float) -> tuple[float, bool] | None:
        """Eq. (2) toward the stop point, and whether it is urgent (None: not braking for it yet).

        The deceleration is the one needed once the reference acceleration has turned into it at the
        jerk limit (the ramp covers ground too), so braking starts early enough; a comfortable stop
        fades out near rest, at the lower of V_des and the measured speed: a vehicle already slower
        than V_des near the point is not braked as if it had V_des (at a bay, clear seed 0, V_des^2 / 2
        gap grew as the gap closed and the wheels stopped with ~0.4 m/s^2 left: +1.97 m/s^3)."""
        c = self.config
        v = self.v_des_mps
        decel = v**2 / (2.0 * gap_m)
        for _ in range(2):
            # Not yet braking, the ramp runs at least to the trigger (so braking starts early enough);
            # braking already, only to what is needed: near rest, ramping to the trigger left no room
            # and turned the end of every stop urgent (at a bay, clear seed 0: -0.49 m/s^2 at 0.1 m/s).
            aim = max(decel, c.brake_trigger_mps2) if not self._braking else decel
            ramp_s = max(self.a_ref_mps2 + aim, 0.0) / c.reference_jerk_mps3
            v_end = max(v + 0.5 * (self.a_ref_mps2 - decel) * ramp_s, 0.0)
            room = gap_m - 0.5 * (v + v_end) * ramp_s
            decel = max(decel, v_end**2 / (2.0 * room) if room > 0.05 else c.max_decel_mps2)
        # Hysteresis: once braking for it, only a stop point that needs half the trigger releases it;
        # once at rest short of it, only one that moved off by ``restart_gap_m`` (no creeping on).
        trigger = c.brake_trigger_mps2 * (0.5 if self._braking else 1.0)
        resting = self._braking and v == 0.0 and gap_m < c.restart_gap_m
        # Within the last metre the stop is braked for at once; but a vehicle reset at rest there (an
        # emergency stop released 0.6-1 m short of a pull-over spot) has not come to rest for it: it
        # approaches as from further away, braking once eq. (2) calls for it. Held at once, it stood
        # 350 s short of the town's West Ave (snow, raw).
        self._braking = decel >= trigger or (gap_m < 1.0 and not self._fresh) or resting
        self._fresh = self._fresh and not self._braking
        if not self._braking:
            return None
        if decel > c.comfort_decel_mps2:
            return -decel, True  # urgent: no fade-out, the stop point comes first
        # The fade-out at the end runs D^3 / (6 j^2) further than constant braking: aim short by that.
        fade_m = decel**3 / (6.0 * c.stop_jerk_mps3**2)
        if fade_m < 0.5 * gap_m:
            decel = max(decel, v**2 / (2.0 * (gap_m - fade_m)))
        fade_v = min(v, max(speed_mps, 0.0))
        return -min(decel, math.sqrt(2.0 * c.stop_jerk_mps3 * fade_v)), False


def stopping_gap_m(stop_front_s_m: float | None, front_s_m: float) -> float | None:
    """Gap from the front bumper to the decision's stop point (None when driving on)."""
    if stop_front_s_m is None or not math.isfinite(stop_front_s_m):
        return None
    return stop_front_s_m - front_s_m


class LongitudinalController(Protocol):
    """Turns the reference speed and the stop gap into an acceleration command (m/s^2)."""

    def reset(self, speed_mps: float) -> None: ...

    def reference_speed_mps(
        self, trajectory: Trajectory | None, path_s_m: float, speed_cap_mps: float
    ) -> float: ...

    def step(self, dt_s: float, speed_mps: float, v_ref_mps: float, gap_to_stop_m: float | None) -> float: ...


class LongitudinalControllerName(StrEnum):
    """Registry names of the longitudinal controllers (the run configuration selects one)."""

    WATONOBUS = "watonobus"  # eqs. (1)-(3), the default
    CASCADED_PI = "cascaded_pi"  # aUToronto: trapezoidal profile + cascaded PI with feed-forward
    GEM_TWIST = "gem_twist"  # GEM: speed P-loop, IMU low-pass, PI throttle, open-loop brake (pedals)


LONGITUDINAL_CONTROLLERS: dict[
    LongitudinalControllerName, Callable[[LongitudinalConfig], LongitudinalController]
] = {
    LongitudinalControllerName.WATONOBUS: WatonobusLongitudinalController,
    LongitudinalControllerName.CASCADED_PI: lambda c: CascadedPiSpeedController(c.cascaded_pi),
    LongitudinalControllerName.GEM_TWIST: lambda c: GemTwistLongitudinalController(
        WatonobusLongitudinalController(c), c.gem_twist
    ),
}


def make_longitudinal_controller(
    name: LongitudinalControllerName | str, config: LongitudinalConfig | None = None
) -> LongitudinalController:
    """The longitudinal controller registered as ``name`` (a plain string is checked against the names)."""
    try:
        key = LongitudinalControllerName(name)
    except ValueError:
        raise ConfigError(
            f"longitudinal controller: expected one of {[n.value for n in LongitudinalControllerName]}, "
            f"got {name!r}"
        ) from None
    return LONGITUDINAL_CONTROLLERS[key](config or LongitudinalConfig())
