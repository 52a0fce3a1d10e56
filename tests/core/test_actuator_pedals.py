"""ActuatorCommand's pedal positions: both or neither, finite, in [0, 1]."""

from __future__ import annotations

import math

import pytest

from lastmile.core.errors import MessageError
from lastmile.core.pedal_map import brake_decel_mps2, gem_brake_pedal
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import ActuatorCommand


def _cmd(**pedals: float | None) -> ActuatorCommand:
    return ActuatorCommand(stamp=Stamp(0), accel_mps2=0.0, steer_front_rad=0.0, steer_rear_rad=0.0, **pedals)  # type: ignore[arg-type]


def test_pedals_default_to_none_and_valid_ones_are_kept() -> None:
    assert not _cmd().has_pedals and _cmd().throttle is None and _cmd().brake is None
    cmd = _cmd(throttle=0.3, brake=0.0)
    assert cmd.has_pedals and cmd.throttle == 0.3


@pytest.mark.parametrize(
    ("pedals", "says"),
    [
        ({"throttle": 0.3}, "both set or both None"),
        ({"brake": 0.3}, "both set or both None"),
        (
            {"throttle": 1.2, "brake": 0.0},
            "ActuatorCommand.throttle: expected a pedal position in [0, 1], got 1.2",
        ),
        (
            {"throttle": 0.0, "brake": -0.1},
            "ActuatorCommand.brake: expected a pedal position in [0, 1], got -0.1",
        ),
        ({"throttle": math.nan, "brake": 0.0}, "ActuatorCommand.throttle: expected a pedal position"),
    ],
)
def test_bad_pedals_are_one_clear_line(pedals: dict[str, float], says: str) -> None:
    with pytest.raises(MessageError, match=r"\A[^\n]*\Z") as err:
        _cmd(**pedals)
    assert says in str(err.value)


def test_gems_brake_map_and_its_inverse_agree() -> None:
    assert gem_brake_pedal(1.0) == pytest.approx(0.90)
    assert gem_brake_pedal(0.0) == 0.0 and gem_brake_pedal(10.0) == 1.0  # clipped to [0, 1]
    for decel in (0.1, 0.5, 1.2):
        assert brake_decel_mps2(gem_brake_pedal(decel)) == pytest.approx(decel)
