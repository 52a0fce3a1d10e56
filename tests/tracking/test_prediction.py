"""Prediction: constant velocity with growing uncertainty; vehicles stop at stop lines; pedestrians cross."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.boxes3d import TRACK_BOX_COLUMNS, TrackedBoxes
from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.predictions import PREDICTION_MODES
from lastmile.core.stamp import Stamp
from lastmile.hdmap.loader import load_campus_map
from lastmile.tracking.prediction import MapAwarePredictor, PredictionConfig, predict_constant_velocity


def _tracks(rows: list[tuple[float, float, float, float, ObjectClass]]) -> TrackedBoxes:
    n = len(rows)
    table = np.zeros((n, len(TRACK_BOX_COLUMNS)))
    for i, (x, y, vx, vy, _) in enumerate(rows):
        table[i, [0, 1, 3, 4, 5, 6, 7, 8, 10]] = [x, y, 4.0, 1.8, 1.5, np.arctan2(vy, vx), vx, vy, 0.2]
    cls = np.array([int(r[4]) for r in rows])
    prob = np.zeros((n, len(ObjectClass)))
    prob[np.arange(n), cls] = 1.0
    return TrackedBoxes(
        stamp=Stamp(0),
        ids=np.arange(n),
        table=table,
        class_id=cls,
        class_prob=prob,
        score=np.ones(n),
        updated=np.ones(n, bool),
        attributes=np.zeros((n, 0)),
    )


def test_constant_velocity_moves_linearly_with_growing_uncertainty() -> None:
    p = predict_constant_velocity(_tracks([(1.0, 2.0, 3.0, -1.0, ObjectClass.CYCLIST)]))
    assert p.times_s[-1] == pytest.approx(5.0) and len(p.times_s) == 10
    assert p.xy_m[0, -1] == pytest.approx([16.0, -3.0])
    assert np.all(np.diff(p.std_m[0]) > 0.0) and p.std_m[0, 0] > 0.2
    assert PREDICTION_MODES[int(p.mode[0])] == "constant_velocity"


def test_vehicle_follows_its_lane_and_stops_at_the_stop_line() -> None:
    hdmap = load_campus_map()  # lanelet 106 runs along y = -1.75 to a stop line at x = 370
    pred = MapAwarePredictor(hdmap).predict(_tracks([(355.0, -1.5, 6.0, 0.3, ObjectClass.CAR)]))
    assert PREDICTION_MODES[int(pred.mode[0])] == "lane_following"
    x = pred.xy_m[0, :, 0]
    assert np.all(np.diff(x) >= -1e-9) and x[-1] == pytest.approx(370.0, abs=0.5)
    assert np.allclose(pred.xy_m[0, :, 1], -1.75, atol=0.05)  # on the centre line, not drifting
    # Constant velocity would have run 30 m past the line.
    assert predict_constant_velocity(_tracks([(355.0, -1.5, 6.0, 0.3, ObjectClass.CAR)])).xy_m[0, -1, 0] > 380


def test_vehicle_driving_against_the_lane_keeps_constant_velocity() -> None:
    pred = MapAwarePredictor(load_campus_map()).predict(_tracks([(300.0, -1.75, -6.0, 0.0, ObjectClass.CAR)]))
    assert PREDICTION_MODES[int(pred.mode[0])] == "constant_velocity"


def test_pedestrian_heading_to_a_crosswalk_crosses_it() -> None:
    hdmap = load_campus_map()  # a crosswalk spans x 168..172, y -3.5..3.5
    walking_to = (169.0, -8.0, 0.3, 1.2, ObjectClass.PEDESTRIAN)
    walking_away = (169.0, -8.0, 0.0, -1.2, ObjectClass.PEDESTRIAN)
    pred = MapAwarePredictor(hdmap, PredictionConfig(horizon_s=12.0)).predict(
        _tracks([walking_to, walking_away])
    )
    assert PREDICTION_MODES[int(pred.mode[0])] == "to_crosswalk"
    assert pred.xy_m[0, -1, 1] > 3.5 and 168.0 <= pred.xy_m[0, -1, 0] <= 172.0
    assert PREDICTION_MODES[int(pred.mode[1])] == "constant_velocity"


def test_bad_prediction_config_is_refused() -> None:
    with pytest.raises(ConfigError, match="step_s"):
        PredictionConfig(step_s=0.0)
