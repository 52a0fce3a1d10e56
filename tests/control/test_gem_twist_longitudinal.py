"""`longitudinal_controller = "gem_twist"`: the twist controller from the registry, reference to pedals."""

from __future__ import annotations

from pathlib import Path

import pytest

from lastmile.control.gem_twist_longitudinal import GemTwistLongitudinalController
from lastmile.control.longitudinal import (
    LongitudinalConfig,
    LongitudinalControllerName,
    make_longitudinal_controller,
)
from lastmile.control.twist_controller import TwistControllerConfig
from lastmile.core.errors import MessageError
from lastmile.core.pedal_map import brake_decel_mps2
from lastmile.runner.run_config import load_run_config

DT = 0.02


def _law(config: LongitudinalConfig | None = None) -> GemTwistLongitudinalController:
    law = make_longitudinal_controller("gem_twist", config)
    assert isinstance(law, GemTwistLongitudinalController)
    return law


def test_selected_by_name_it_opens_the_throttle_toward_the_reference() -> None:
    law = _law()
    law.reset(0.0)
    law.observe_imu(0.0)
    for _ in range(50):
        accel = law.step(DT, 0.0, 5.0, None)
    assert accel > 0.0 and law.pedals.throttle > 0.1 and law.pedals.brake == 0.0
    assert law.pedals.accel_cmd_mps2 == accel


def test_a_near_stop_point_brakes_by_gems_map_and_holds_at_rest() -> None:
    law = _law()
    law.reset(4.0)
    law.observe_imu(0.0)
    for _ in range(10):
        law.step(DT, 4.0, 5.0, 6.0)  # 6 m to the stop point at 4 m/s: 1.3 m/s^2 needed
    assert law.pedals.throttle == 0.0 and law.pedals.brake > 0.5
    for _ in range(50):
        law.step(DT, 0.0, 5.0, 0.0)  # at the point, at rest
    assert law.pedals.throttle == 0.0 and law.pedals.brake == pytest.approx(
        TwistControllerConfig().hold_brake
    )


def test_its_parameters_come_from_the_longitudinal_table() -> None:
    law = _law(LongitudinalConfig(gem_twist=TwistControllerConfig(imu_lowpass_tau_s=1.0)))
    assert law.twist.config.imu_lowpass_tau_s == 1.0


def test_without_an_imu_frame_it_says_so() -> None:
    law = _law()
    with pytest.raises(MessageError, match="expected an IMU frame first"):
        law.step(DT, 0.0, 5.0, None)


def test_the_example_configuration_selects_it_with_the_pedal_brakes_reach() -> None:
    config = load_run_config(Path(__file__).parents[2] / "examples/configs/gem_twist.toml")
    stack = config.stack
    assert stack.longitudinal_controller is LongitudinalControllerName.GEM_TWIST
    assert stack.longitudinal.gem_twist == TwistControllerConfig()  # GEM's published constants, spelled out
    full_pedal_mps2 = brake_decel_mps2(1.0)
    assert stack.longitudinal.comfort_decel_mps2 <= full_pedal_mps2
    assert stack.decision.traffic_lights.comfort_decel_mps2 <= full_pedal_mps2
