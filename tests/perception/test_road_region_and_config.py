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


def test_road_mask_is_exact_at_the_edge_of_the_road(straight_map):
    # Next to a curb, a sidewalk point 5-30 cm off the road must not be called road (the raster's
    # edge cells are up to half a metre wide): it would stand 0.15 m out of the road's plane.
    region = MapRoadRegion(straight_map)
    top = float(straight_map.lanelets[1].polygon()[:, 1].max())
    x = np.linspace(10.0, 90.0, 41)
    for dy, on_road in ((-0.3, True), (-0.05, True), (0.05, False), (0.12, False), (0.3, False)):
        xy = np.c_[x, np.full_like(x, top + dy)]
        assert region.contains(xy).tolist() == [on_road] * len(x), dy
    # The same through the vehicle-frame mask.
    mask = region.mask_for(SE2(40.0, top - 2.0, 0.0))
    assert mask(np.array([[5.0, 1.9], [5.0, 2.1]])).tolist() == [True, False]
