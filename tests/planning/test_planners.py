"""The path planner the run configuration names is the one the stack plans with."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.polyline import Polyline
from lastmile.planning.lattice_planner import LatticePlanner
from lastmile.planning.local_path import LocalPathPlanner
from lastmile.planning.pass_path import OffsetPassPlanner
from lastmile.planning.planners import PlannerInputs, PlannerName, make_path_planner
from lastmile.planning.snow_lion_behaviour import SnowLionBehaviourPlanner


def _inputs() -> PlannerInputs:
    return PlannerInputs(route=Polyline(np.array([[0.0, 0.0], [100.0, 0.0]])), half_width_m=1.0)


def test_every_registered_name_builds_its_planner() -> None:
    planner = make_path_planner(PlannerName.POTENTIAL_FIELD_BEZIER, _inputs())
    assert isinstance(planner, LocalPathPlanner) and planner.half_width_m == 1.0
    assert isinstance(make_path_planner("potential_field_bezier", _inputs()), LocalPathPlanner)
    assert isinstance(make_path_planner("offset_pass", _inputs()), OffsetPassPlanner)
    assert isinstance(make_path_planner("snow_lion_behaviour", _inputs()), SnowLionBehaviourPlanner)
    assert isinstance(make_path_planner("lattice", _inputs()), LatticePlanner)


def test_an_unknown_planner_is_named_with_the_known_ones() -> None:
    expected = (
        r"planner: expected one of \['potential_field_bezier', 'offset_pass', 'snow_lion_behaviour', "
        r"'lattice'\], got 'free_space'"
    )
    with pytest.raises(ConfigError, match=expected):
        make_path_planner("free_space", _inputs())
