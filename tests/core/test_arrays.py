"""Message arrays: read-only, checked, copied unless handed over; validation without a copy."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.arrays import check_frozen_array, frozen_array
from lastmile.core.errors import MessageError
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.stamp import Stamp


def test_a_writable_array_or_a_view_is_copied_and_an_owned_read_only_one_is_taken_as_it_is() -> None:
    writable = np.ones((3, 6), dtype=np.float32)
    out = frozen_array(writable, np.float32, 6, "x")
    assert out is not writable and not out.flags.writeable
    writable[0, 0] = 5.0
    assert out[0, 0] == 1.0  # the message keeps its own copy
    handed = np.ones((3, 6), dtype=np.float32)
    handed.setflags(write=False)
    assert frozen_array(handed, np.float32, 6, "x") is handed
    view = handed[1:]
    assert frozen_array(view, np.float32, 6, "x") is not view
    # Another dtype is converted (a copy) even when read-only.
    assert frozen_array(handed, np.float64, 6, "x").dtype == np.float64


@pytest.mark.parametrize(
    "values",
    [
        np.ones((3, 5), dtype=np.float32),
        np.ones(6, dtype=np.float32),
        np.array([[0.0, 1, 2, 3, 4, np.nan]], dtype=np.float32),
        np.array([[0.0, 1, 2, 3, 4, np.inf]], dtype=np.float32),
        np.array([[0.0, 1, 2, 3, 4, 5]], dtype=np.float64),
        [[0.0, 1, 2, 3, 4, 5]],
        np.zeros((0,), dtype=np.float32),
    ],
)
def test_checking_in_place_raises_exactly_when_freezing_does(values: object) -> None:
    def outcome(fn: object) -> str:
        try:
            fn(values, np.float32, 6, "LidarSweep.points")  # type: ignore[operator]
        except MessageError as exc:
            return str(exc)
        return ""

    assert outcome(check_frozen_array) == outcome(frozen_array)


def test_a_sweep_made_invalid_after_construction_fails_its_validation() -> None:
    sweep = LidarSweep(stamp=Stamp(0), sensor_id="front", points=np.zeros((2, 6), dtype=np.float32))
    sweep.validate()
    bad = np.zeros((2, 6), dtype=np.float32)
    bad[1, 2] = np.nan
    object.__setattr__(sweep, "points", bad)  # a corrupt driver that bypassed the constructor
    with pytest.raises(MessageError, match="finite"):
        sweep.validate()
