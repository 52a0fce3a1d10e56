"""Ground segmentation separates sloped ground from objects standing on it, for both methods."""

from __future__ import annotations

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.perception.ground import (
    AdaptiveGridConfig,
    AdaptiveGridGroundSegmenter,
    HimmelsbachGroundSegmenter,
    make_ground_segmenter,
)
from lastmile.perception.himmelsbach import HimmelsbachConfig
from tests.perception.synthetic import Box, Scene, base_cloud, default_rig


def _scene(grade: float) -> Scene:
    boxes = (
        Box((8.0, -2.0, 8.0 * grade), (12.5, 0.0, 8.0 * grade + 1.5)),  # a car
        Box((15.0, 2.0, 15.0 * grade), (15.5, 2.5, 15.0 * grade + 1.7)),  # a pedestrian
        *(
            Box((x, 1.0, x * grade), (x + 0.6, 1.3, x * grade + 0.4)) for x in (12.0, 16.0, 21.0, 27.0)
        ),  # geese
        Box((20.0, -3.0, 20.0 * grade), (21.0, -1.0, 20.0 * grade + 0.25)),  # a low kerb-like block
    )
    # A wide flat road so the slope, not a curb, is the test.
    return Scene(profile_y=(-30.0, 30.0), profile_z=(0.0, 0.0), grade=grade, boxes=boxes)


@pytest.mark.parametrize("name", ["adaptive_grid", "himmelsbach"])
@pytest.mark.parametrize("grade", [0.0, 0.06, -0.04])
def test_sloped_ground_is_ground_and_objects_are_not(name, grade):
    rng = np.random.default_rng(1)
    xyz, _, box = base_cloud(_scene(grade), default_rig()[0], rng)
    near = np.hypot(xyz[:, 0], xyz[:, 1]) < 40.0
    ground = make_ground_segmenter(name).segment(xyz)
    height = xyz[:, 2] - grade * xyz[:, 0]
    terrain = near & (box == -1)
    # Tolerances grow to 0.2 m at 20 m range and a line may tilt up a vertical face's foot, so
    # "object" means 0.5 m up or more.
    tall = near & (box >= 0) & (height > 0.5)
    assert ground[terrain].mean() >= 0.97
    assert (~ground[tall]).mean() >= 0.97
    # Geese (boxes 2-5) above the range-dependent tolerance (0.2 m at 20 m) plus 5 cm.
    goose = (
        (box >= 2)
        & (box <= 5)
        & (height > AdaptiveGridConfig().threshold_m(np.hypot(xyz[:, 0], xyz[:, 1])) + 0.05)
    )
    # The goose comes out: the adaptive grid keeps all of it above 0.25 m; Himmelsbach's lines may
    # swallow part of a small object whose returns hide the ground behind it, but not most of it.
    if grade >= 0.0:  # downhill the VLP-32C's beams only graze the geese's feet (h < 0.12 m)
        assert goose.sum() > 5
    if goose.any():
        assert (~ground[goose]).mean() >= (1.0 if name == "adaptive_grid" else 0.5)


def test_adaptive_grid_uses_separate_road_and_off_road_planes():
    # Road at z = 0 for y > -3.5; a sidewalk plateau 0.35 m higher beyond: one plane per cell would
    # have to split the difference, separate road/off-road planes fit both.
    scene = Scene(profile_y=(-30.0, -3.51, -3.5, 30.0), profile_z=(0.35, 0.35, 0.0, 0.0))
    rng = np.random.default_rng(2)
    xyz, _, _ = base_cloud(scene, default_rig()[0], rng)
    keep = np.hypot(xyz[:, 0], xyz[:, 1]) < 30
    xyz = xyz[keep]
    seg = AdaptiveGridGroundSegmenter()
    with_map = seg.segment(xyz, road_mask=lambda xy: xy[:, 1] > -3.5)
    assert with_map.mean() >= 0.97


def test_registry_rejects_unknown_names_and_wrong_configs():
    with pytest.raises(ConfigError, match="expected one of"):
        make_ground_segmenter("ransac")
    with pytest.raises(ConfigError, match="expected HimmelsbachConfig"):
        make_ground_segmenter("himmelsbach", AdaptiveGridConfig())
    assert isinstance(make_ground_segmenter("himmelsbach", HimmelsbachConfig()), HimmelsbachGroundSegmenter)


def test_config_validation_names_the_field():
    with pytest.raises(ConfigError, match="sectors_per_ring"):
        AdaptiveGridConfig(sectors_per_ring=(4,))
    with pytest.raises(ConfigError, match="small_slope"):
        HimmelsbachConfig(small_slope=0.5)


def test_threshold_grows_with_range_and_is_capped():
    cfg = AdaptiveGridConfig()
    t = cfg.threshold_m(np.array([0.0, 20.0, 500.0]))
    assert t[0] == cfg.threshold_near_m and t[0] < t[1] < t[2] == cfg.threshold_max_m


def test_empty_cloud():
    for name in ("adaptive_grid", "himmelsbach"):
        assert make_ground_segmenter(name).segment(np.zeros((0, 3))).shape == (0,)


def test_a_cell_that_sees_only_a_car_side_keeps_the_prior_plane_and_the_car_stays_an_object():
    # Ring 20-30 m behind the bus: the road there is hidden, a horizontal beam draws one line along
    # a car's side at 0.9 m. The inner rings see flat road.
    rng = np.random.default_rng(3)
    r = rng.uniform(2.0, 19.5, 4000)
    a = rng.uniform(-np.pi, np.pi, 4000)
    road = np.c_[r * np.cos(a), r * np.sin(a), rng.normal(0.0, 0.01, 4000)]
    car = np.c_[np.linspace(-26.0, -22.0, 25), np.full(25, 2.5), np.full(25, 0.9)]
    ground = AdaptiveGridGroundSegmenter().segment(np.vstack([road, car]))
    assert ground[:4000].mean() > 0.99
    assert not ground[4000:].any()
    # Without the step limit the cell fits its plane through the car (the failure this guards).
    loose = AdaptiveGridGroundSegmenter(AdaptiveGridConfig(max_step_m=5.0)).segment(np.vstack([road, car]))
    assert loose[4000:].all()


def test_a_grazed_goose_body_on_a_smooth_road_is_not_ground_but_road_texture_is() -> None:
    # A smooth paved road (1 cm noise) and one ring grazing a goose's body 0.10-0.13 m up at 9.8 m:
    # within the range-dependent tolerance (0.16 m there), but 10 sigma off the fitted surface.
    rng = np.random.default_rng(4)
    xy = rng.uniform(-25.0, 25.0, (40_000, 2))
    road = np.c_[xy, rng.normal(0.0, 0.01, len(xy))]
    t = np.linspace(-0.15, 0.15, 12)
    goose = np.c_[9.3 + t, 3.0 - t, 0.115 + 0.015 * np.cos(t * 10.0)]
    rut = np.c_[-9.3 + t, 3.0 - t, np.full(12, 0.06)]  # a 6 cm ridge of the road's own surface
    xyz = np.vstack([road, goose, rut])
    ground = AdaptiveGridGroundSegmenter().segment(xyz)
    assert not ground[len(road) : len(road) + 12].any()
    assert ground[-12:].all()
    assert ground[: len(road)].mean() > 0.999
    # Without the smooth-surface rule the range-dependent tolerance calls the goose ground.
    loose = AdaptiveGridGroundSegmenter(AdaptiveGridConfig(smooth_floor_m=1.0)).segment(xyz)
    assert loose[len(road) : len(road) + 12].all()
    # A rough surface (4 cm noise) keeps its range-dependent tolerance: 4 sigma is above it.
    rough = np.c_[xy, rng.normal(0.0, 0.04, len(xy))]
    g2 = AdaptiveGridGroundSegmenter().segment(rough)
    assert g2.mean() > 0.995


def _level_change_scan(ped_x_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A VLP-32C 1.9 m up over a road that drops 1.7 m at x = 15 m (a wall face below the edge),
    a pedestrian (0.5 x 0.5 x 1.7 m) standing on the lower road; ray cast (shadow behind the edge
    included). Returns the (N, 3) points and which are the pedestrian's."""
    from lastmile.perception.lidar_model import VLP32C_ELEVATIONS_DEG

    height, edge, drop = 1.9, 15.0, 1.7
    az, el = np.meshgrid(np.radians(np.arange(-180, 180, 0.2)), np.radians(VLP32C_ELEVATIONS_DEG))
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    down = d[:, 2] < -1e-6
    t_upper = np.where(down, height / np.maximum(-d[:, 2], 1e-9), np.inf)
    upper = down & (t_upper * d[:, 0] < edge)
    t = np.where(upper, t_upper, np.where(down, (height + drop) / np.maximum(-d[:, 2], 1e-9), np.inf))
    lo = np.array([ped_x_m, -0.25, -drop - height])
    hi = np.array([ped_x_m + 0.5, 0.25, -drop - height + 1.7])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = lo / d, hi / d
    t_in, t_out = np.nanmax(np.minimum(t1, t2), 1), np.nanmin(np.maximum(t1, t2), 1)
    ped = (t_in <= t_out) & (t_in > 0) & (t_in < t)
    t = np.where(ped, t_in, t)
    keep = np.isfinite(t) & (t < 60.0)
    return d[keep] * t[keep][:, None] + [0.0, 0.0, height], ped[keep]


@pytest.mark.parametrize("ped_x_m", [30.0, 35.0])
def test_a_pedestrian_below_a_level_change_is_not_ground(ped_x_m):
    xyz, ped = _level_change_scan(ped_x_m)
    lower_road = (xyz[:, 0] > 15.0) & ~ped
    ground = AdaptiveGridGroundSegmenter().segment(xyz)
    assert ground[~ped].mean() > 0.99 and ground[lower_road].mean() > 0.99
    # The pedestrian's lowest visible row is its bin's prototype (Himmelsbach's line runs through
    # it; the shadow of the edge hides the feet); every row above it is not ground.
    above = ped & (xyz[:, 2] > xyz[ped, 2].min() + 0.1)
    assert above.sum() >= 15 and not ground[above].any()
    # The grid alone keeps the plane of the upper road, and everything below it is ground.
    plain = AdaptiveGridGroundSegmenter(AdaptiveGridConfig(level_change_fallback=False)).segment(xyz)
    assert plain[ped].all()


@pytest.mark.parametrize("map_error_m", [0.1, 0.2])
def test_a_sidewalk_strip_the_map_calls_road_is_ground_and_an_object_at_the_edge_is_not(map_error_m):
    # A 0.15 m sidewalk beyond y = -3.5 on both sides; the map's road edge lies map_error_m out on
    # the sidewalk (map and localization error), so a strip of sidewalk falls in the road part.
    scene = Scene(
        profile_y=(-30.0, -3.51, -3.5, 3.5, 3.51, 30.0),
        profile_z=(0.15, 0.15, 0.0, 0.0, 0.15, 0.15),
        boxes=(Box((10.0, -3.6, 0.15), (10.5, -3.3, 1.05)),),  # a bin standing on the edge
    )
    rng = np.random.default_rng(3)
    xyz, _, box = base_cloud(scene, default_rig()[0], rng)
    xyz, box = xyz[np.hypot(xyz[:, 0], xyz[:, 1]) < 30], box[np.hypot(xyz[:, 0], xyz[:, 1]) < 30]
    edge = 3.5 + map_error_m

    def road(xy: np.ndarray) -> np.ndarray:
        return np.abs(xy[:, 1]) < edge

    strip = (box == -1) & (np.abs(xyz[:, 1]) > 3.52) & (np.abs(xyz[:, 1]) < edge)
    assert strip.sum() > 20
    off = AdaptiveGridGroundSegmenter(AdaptiveGridConfig(edge_margin_m=0.0)).segment(xyz, road)
    # The leak: near the bus (tolerance 0.12 m + 4 mm/m) the strip stands out of the road plane.
    assert (~off[strip]).sum() >= 10
    ground = AdaptiveGridGroundSegmenter().segment(xyz, road)
    assert ground[box == -1].mean() >= 0.995
    # The bin's returns more than the tolerance above the sidewalk stay obstacles.
    tall = (box == 0) & (xyz[:, 2] > 0.15 + 0.25)
    assert tall.sum() > 10 and not ground[tall].any()


def test_edge_margin_is_validated():
    with pytest.raises(ConfigError, match="edge_margin_m"):
        AdaptiveGridConfig(edge_margin_m=-0.1)
