import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.tracking.radar_class import RadarClassConfig, classify_radar_tracks

CONFIG = RadarClassConfig()


def _classify(rcs_dbsm, max_speed_mps, hits=20):
    out = classify_radar_tracks(
        np.array([rcs_dbsm]), np.array([float(hits)]), np.array([max_speed_mps]), CONFIG
    )
    return ObjectClass(int(out[0]))


@pytest.mark.parametrize(
    ("rcs_dbsm", "max_speed_mps", "expected"),
    [
        (10.0, 0.0, ObjectClass.CAR),  # parked car
        (8.0, 12.0, ObjectClass.CAR),
        (-5.0, 1.4, ObjectClass.PEDESTRIAN),
        (-2.0, 6.0, ObjectClass.CYCLIST),
        (-16.0, 0.3, ObjectClass.ANIMAL),  # goose standing or waddling
        (-16.0, 4.0, ObjectClass.UNKNOWN),  # goose-sized but too fast for a goose
        (-10.0, 0.5, ObjectClass.UNKNOWN),  # halfway between a goose and a person
        (2.0, 1.0, ObjectClass.UNKNOWN),  # halfway between a person and a car
        (-30.0, 0.0, ObjectClass.UNKNOWN),  # nothing we know returns so little
        (-5.0, 20.0, ObjectClass.UNKNOWN),  # person-sized at car speed
    ],
)
def test_rcs_and_speed_evidence_map_to_a_class_or_unknown(rcs_dbsm, max_speed_mps, expected):
    assert _classify(rcs_dbsm, max_speed_mps) == expected


def test_many_tracks_are_classified_at_once_in_order():
    out = classify_radar_tracks(
        np.array([10.0, -5.0, -16.0]), np.array([5.0, 5.0, 5.0]), np.array([3.0, 1.0, 0.2]), CONFIG
    )
    assert out.tolist() == [ObjectClass.CAR, ObjectClass.PEDESTRIAN, ObjectClass.ANIMAL]
    assert classify_radar_tracks(np.zeros(0), np.zeros(0), np.zeros(0), CONFIG).shape == (0,)


def test_inconsistent_speed_limits_are_rejected():
    with pytest.raises(ConfigError, match="animal_max_speed_mps <= pedestrian_max_speed_mps"):
        RadarClassConfig(animal_max_speed_mps=4.0, pedestrian_max_speed_mps=3.0)
