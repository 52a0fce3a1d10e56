"""GEM's twist controller as a longitudinal controller: speed reference and stop gap -> pedals.

GEM's controller (its section II, Fig. 3) takes a target speed. Ours gets it from the WATonoBus law's
reference (eqs. 1-3: V_des toward the reference speed, braking toward the stop gap with the jerk limits
and the fade-out of ``control.longitudinal``): the target handed to GEM's P-loop is V_des + a_ref / k_p,
so that loop's command k_p (target - v) is a_ref + k_p (V_des - v). Without that feed-forward a pure
P-loop trails a decelerating reference by a / k_p (0.6 m/s at 0.6 m/s^2 with GEM-like k_p = 1 /s) and
runs about v0 / k_p (3 m at 3 m/s) past every stop point. GEM's own parts are kept as published: the
IMU acceleration low-pass (tau = 2 s), the PI throttle and the open-loop brake map.

The IMU's longitudinal acceleration reaches it through ``observe_imu`` (the stack forwards each IMU
frame); ``pedals`` is the last step's throttle and brake, which the stack puts on its command.
"""

from __future__ import annotations

from typing import Protocol

from lastmile.control.twist_controller import GemTwistController, PedalCommand, TwistControllerConfig
from lastmile.core.errors import MessageError
from lastmile.core.vehicle_messages import Trajectory


class SpeedReference(Protocol):
    """The reference half of a longitudinal law: V_des and the acceleration it integrates (WATonoBus's)."""

    v_des_mps: float
    a_ref_mps2: float

    def reset(self, speed_mps: float) -> None: ...

    def reference_speed_mps(
        self, trajectory: Trajectory | None, path_s_m: float, speed_cap_mps: float
    ) -> float: ...

    def step(self, dt_s: float, speed_mps: float, v_ref_mps: float, gap_to_stop_m: float | None) -> float: ...


class GemTwistLongitudinalController:
    """The ``gem_twist`` longitudinal controller (registry ``LongitudinalControllerName.GEM_TWIST``)."""

    def __init__(self, reference: SpeedReference, config: TwistControllerConfig | None = None) -> None:
        self.reference = reference
        self.twist = GemTwistController(config)
        self._imu_accel_mps2: float | None = None
        self.pedals = PedalCommand(throttle=0.0, brake=0.0, accel_cmd_mps2=0.0)

    def reset(self, speed_mps: float) -> None:
        self.reference.reset(speed_mps)
        self.twist.reset()

    def observe_imu(self, accel_x_mps2: float) -> None:
        """The IMU's latest longitudinal acceleration (body x, m/s^2)."""
        self._imu_accel_mps2 = accel_x_mps2

    def reference_speed_mps(
        self, trajectory: Trajectory | None, path_s_m: float, speed_cap_mps: float
    ) -> float:
        return self.reference.reference_speed_mps(trajectory, path_s_m, speed_cap_mps)

    def step(self, dt_s: float, speed_mps: float, v_ref_mps: float, gap_to_stop_m: float | None) -> float:
        """Advance the reference and the twist controller; returns its acceleration command (m/s^2).

        Raises:
            MessageError: no IMU frame has arrived yet (GEM's throttle loop closes on the IMU).
        """
        if self._imu_accel_mps2 is None:
            raise MessageError("GemTwistLongitudinalController.step: expected an IMU frame first, got none")
        self.reference.step(dt_s, speed_mps, v_ref_mps, gap_to_stop_m)
        v_des, a_ref = self.reference.v_des_mps, self.reference.a_ref_mps2
        target = v_des + a_ref / self.twist.config.speed_kp_per_s if v_des > 0.0 else 0.0
        self.pedals = self.twist.step(dt_s, speed_mps, self._imu_accel_mps2, target)
        return self.pedals.accel_cmd_mps2
