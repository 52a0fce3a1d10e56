"""HD-map road regions as a point mask; the pipeline config loads from a TOML-like table."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.config import from_mapping
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.perception.pipeline import LidarPipelineConfig
from lastmile.perception.road_region import MapRoadRegion


def test_road_mask_follows_the_vehicle_pose(straight_map):
    region = MapRoadRegion(straight_map)
    mask = region.mask_for(SE2(40.0, 0.0, 0.0))
    # Base (10, 0) is map (50, 0): on the lane; base (10, 6) is map (50, 6): off the road.
    assert mask(np.array([[10.0, 0.0], [10.0, 6.0], [10.0, -1.5]])).tolist() == [True, False, True]
    turned = region.mask_for(SE2(50.0, -10.0, np.pi / 2))  # facing +y: base x points along map y
    # Base (10, 0) is map (50, 0), on the lane; base (16, 0) is map (50, 6), off it.
    assert turned(np.array([[10.0, 0.0], [16.0, 0.0]])).tolist() == [True, False]


def test_pipeline_config_from_a_table_and_unknown_keys_are_refused():
    cfg = from_mapping(
        LidarPipelineConfig,
        {
            "ground": "himmelsbach",
            "cluster_eps_m": 0.4,
            "dror": {"min_neighbours": 4},
            "curb": {"band_m": 1.2},
        },
        "perception",
    )
    assert cfg.ground == "himmelsbach" and cfg.dror.min_neighbours == 4 and cfg.curb.band_m == 1.2
    with pytest.raises(ConfigError, match="unknown key 'eps'"):
        from_mapping(LidarPipelineConfig, {"eps": 0.4}, "perception")
    with pytest.raises(ConfigError, match="residual_degree"):
        from_mapping(LidarPipelineConfig, {"curb": {"residual_degree": 5}}, "perception")
