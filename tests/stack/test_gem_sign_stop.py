"""GEM's sign detector wired as a stop (``[stack.gem_sign_stop]``): synthetic clouds on the straight
test road (route along +x, lane centre y = 0, the shuttle's rear axle at x = 0)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import LocalizationEstimate
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig
from lastmile.hdmap.layers import RouteStopLine, SLayerDatabase
from lastmile.hdmap.model import Landmark, StopLine
from lastmile.stack.gem_sign_stop import GemSignStop, GemSignStopSettings, SignCheck
from lastmile.stack.stack_settings import StackSettings

FRONT_M = 3.0
RULE = TrafficLightRuleConfig()


def _plate(x_m: float, y_m: float, rng: np.random.Generator) -> np.ndarray:
    """A 0.6 m x 0.6 m retro-reflective plate facing -x, centred 2 m up, as a LiDAR samples it (the
    nearer, the denser)."""
    n_y, n_z = round(13 * 30.0 / x_m), round(9 * 30.0 / x_m)
    ys, zs = np.meshgrid(np.linspace(y_m - 0.3, y_m + 0.3, n_y), np.linspace(1.7, 2.3, n_z))
    n = ys.size
    return np.column_stack(
        [x_m + rng.normal(0.0, 0.01, n), ys.ravel(), zs.ravel(), rng.uniform(180.0, 230.0, n)]
    )


def _cloud(plates: list[tuple[float, float]], seed: int = 0) -> np.ndarray:
    """Dark road around the shuttle and the given plates (x, y), base frame."""
    rng = np.random.default_rng(seed)
    road = np.column_stack(
        [rng.uniform(-10, 45, 3000), rng.uniform(-8, 8, 3000), np.zeros(3000), rng.uniform(2, 30, 3000)]
    )
    return np.vstack([road, *(_plate(x, y, rng) for x, y in plates)])


def _estimate(x_m: float = 0.0, speed_mps: float = 4.0) -> LocalizationEstimate:
    return LocalizationEstimate(
        stamp=Stamp(0),
        map_from_base=SE2(x_m, 0.0, 0.0),
        speed_mps=speed_mps,
        yaw_rate_radps=0.0,
        pos_std_m=0.05,
        yaw_std_rad=0.01,
        valid=True,
    )


def _sign(lid: int, x_m: float, y_m: float, subtype: str) -> Landmark:
    # The plate across the road (its normal along x), as the map draws a sign facing the traffic.
    return Landmark(
        id=lid, kind="sign", xy=np.array([[x_m, y_m + 0.3], [x_m, y_m - 0.3]]), height_m=2.0, subtype=subtype
    )


def _layers(
    base: SLayerDatabase, signs: tuple[Landmark, ...] = (), line_x_m: float | None = None
) -> SLayerDatabase:
    lines: tuple[RouteStopLine, ...] = ()
    if line_x_m is not None:
        sl = StopLine(
            id=9, line=np.array([[line_x_m, -1.75], [line_x_m, 1.75]]), lanelet_id=1, stop_sign_id=5
        )
        lines = (RouteStopLine(stop_line=sl, s_m=line_x_m, all_way_stop_id=None),)
    return dataclasses.replace(base, hdmap=dataclasses.replace(base.hdmap, landmarks=signs), stop_lines=lines)


def _stop(layers: SLayerDatabase, check: SignCheck = SignCheck.GEM) -> GemSignStop:
    return GemSignStop(GemSignStopSettings(check=check), layers, FRONT_M, RULE)


def test_a_facing_plate_beside_the_lane_gives_a_stop_before_it_approached_at_gems_deceleration(
    straight_layers: SLayerDatabase,
) -> None:
    stop = _stop(_layers(straight_layers))
    stop.update(_cloud([(40.0, -3.2)]), _estimate(speed_mps=4.0), rear_s_m=0.0)
    front_s = FRONT_M
    stop_s, why = stop.step(0.0, front_s, 4.0)
    assert stop_s == pytest.approx(40.0 - 0.5, abs=0.1)  # the sign's along-route s minus the setback
    assert "GEM sign detector" in why
    # GEM's a = v^2 / (2 d) at the first detection (4 m/s, 36.5 m to the stop point), above its floor.
    a = 4.0**2 / (2.0 * (stop_s - front_s))
    assert stop.signs[0].decel_mps2 == pytest.approx(max(a, 0.45), rel=0.01)
    gap = 20.0
    assert stop.cap_mps(10.0, stop_s - gap) == pytest.approx(math.sqrt(2.0 * stop.signs[0].decel_mps2 * gap))
    assert stop.cap_mps(1.0, stop_s - gap) == 1.0  # never above the cap it is given
    assert stop.counters()["gem_sign_detections"] == 1


@pytest.mark.parametrize(
    ("x_m", "y_m", "why"),
    [
        (20.0, 6.5, "left of the lane: the opposite approach's plate"),
        (20.0, -7.0, "too far right of the lane"),
        (2.0, -3.2, "behind the front bumper"),
    ],
)
def test_a_plate_outside_the_corridor_gives_no_stop(
    straight_layers: SLayerDatabase, x_m: float, y_m: float, why: str
) -> None:
    stop = _stop(_layers(straight_layers))
    stop.update(_cloud([(x_m, y_m)]), _estimate(), rear_s_m=0.0)
    assert stop.step(0.0, FRONT_M, 4.0) == (None, ""), why
    assert stop.counters()["gem_sign_detections"] == 0, why


def test_the_corridor_lets_the_farther_sign_through_past_a_nearer_plate_outside_it(
    straight_layers: SLayerDatabase,
) -> None:
    # GEM returns the nearest sign only: a plate across the road must not hide the lane's own.
    stop = _stop(_layers(straight_layers))
    stop.update(_cloud([(15.0, 6.5), (30.0, -3.2)]), _estimate(), rear_s_m=0.0)
    stop_s, _ = stop.step(0.0, FRONT_M, 4.0)
    assert stop_s == pytest.approx(29.5, abs=0.1)


def test_the_same_sign_seen_again_gives_one_full_stop(straight_layers: SLayerDatabase) -> None:
    stop = _stop(_layers(straight_layers))
    cloud = _cloud([(30.0, -3.2)])
    stop.update(cloud, _estimate(), rear_s_m=0.0)
    stop_s, _ = stop.step(0.0, FRONT_M, 4.0)
    assert stop_s is not None
    # Standing 0.2 m before the point: held for the full stop, then released.
    rear = stop_s - 0.2 - FRONT_M
    assert stop.step(10.0, rear + FRONT_M, 0.0)[0] == stop_s
    assert stop.step(10.0 + RULE.full_stop_s - 0.1, rear + FRONT_M, 0.0)[0] == stop_s
    released, why = stop.step(10.0 + RULE.full_stop_s, rear + FRONT_M, 0.0)
    assert released is None and "stopped, go" in why
    # The plate, seen again from where the shuttle stands and as it drives off: no second stop.
    for dx in (0.0, 1.0, 2.0):
        shifted = cloud - np.array([rear + dx, 0.0, 0.0, 0.0])
        stop.update(shifted, _estimate(x_m=rear + dx), rear_s_m=rear + dx)
        assert stop.step(12.0 + dx, rear + dx + FRONT_M, 1.0) == (None, "")
    assert stop.counters()["gem_sign_stops"] == 1
    assert len(stop.signs) == 1
    # Once it is behind the rear axle it is forgotten: a sign there next lap is owed a stop again.
    stop.update(_cloud([]), _estimate(x_m=31.0), rear_s_m=31.0)
    assert stop.signs == [] and stop.counters()["gem_sign_passed_unserved"] == 0


@pytest.mark.parametrize(
    ("subtype", "sign_y_m", "counts"),
    [
        ("de206", -3.2, True),
        ("us:R1-1", -3.0, True),  # a mapped stop sign within the match radius of the detection
        ("de224", -3.2, False),  # a bus-stop plate: LiDAR sees the same retro-reflective plate
        ("de206", -7.5, False),  # a mapped stop sign, but 4.3 m from the detection
    ],
)
def test_the_map_check_counts_a_plate_only_where_the_map_has_a_stop_sign(
    straight_layers: SLayerDatabase, subtype: str, sign_y_m: float, counts: bool
) -> None:
    layers = _layers(straight_layers, signs=(_sign(5, 30.0, sign_y_m, subtype),))
    stop = _stop(layers, SignCheck.MAP_CHECKED)
    stop.update(_cloud([(30.0, -3.2)]), _estimate(), rear_s_m=0.0)
    assert (stop.step(0.0, FRONT_M, 4.0)[0] is not None) is counts
    assert stop.counters()["gem_sign_detections_rejected"] == (0 if counts else 1)
    # GEM's own mode stops at it either way.
    gem = _stop(layers, SignCheck.GEM)
    gem.update(_cloud([(30.0, -3.2)]), _estimate(), rear_s_m=0.0)
    assert gem.step(0.0, FRONT_M, 4.0)[0] is not None


def test_a_mapped_sign_across_the_road_does_not_confirm_a_plate(straight_layers: SLayerDatabase) -> None:
    side = Landmark(
        id=5, kind="sign", xy=np.array([[29.7, -3.2], [30.3, -3.2]]), height_m=2.0, subtype="de206"
    )
    stop = _stop(_layers(straight_layers, signs=(side,)), SignCheck.MAP_CHECKED)
    stop.update(_cloud([(30.0, -3.2)]), _estimate(), rear_s_m=0.0)
    assert stop.step(0.0, FRONT_M, 4.0)[0] is None


def test_the_stop_moves_to_the_signs_mapped_line(straight_layers: SLayerDatabase) -> None:
    stop = _stop(_layers(straight_layers, line_x_m=31.5))
    stop.update(_cloud([(30.0, -3.2)]), _estimate(), rear_s_m=0.0)
    assert stop.step(0.0, FRONT_M, 4.0)[0] == pytest.approx(31.0, abs=1e-6)
    far = _stop(_layers(straight_layers, line_x_m=45.0))  # 15 m past the sign: another line's
    far.update(_cloud([(30.0, -3.2)]), _estimate(), rear_s_m=0.0)
    assert far.step(0.0, FRONT_M, 4.0)[0] == pytest.approx(29.5, abs=0.1)


def test_a_detection_at_rest_still_lets_the_shuttle_reach_the_sign(straight_layers: SLayerDatabase) -> None:
    stop = _stop(_layers(straight_layers))
    stop.update(_cloud([(30.0, -3.2)]), _estimate(speed_mps=0.0), rear_s_m=0.0)
    assert stop.signs[0].decel_mps2 == GemSignStopSettings().min_decel_mps2
    assert stop.cap_mps(10.0, FRONT_M) > 4.0


def test_a_plate_first_seen_too_close_to_stop_comfortably_is_not_stopped_for(
    straight_layers: SLayerDatabase,
) -> None:
    # 5.5 m/s with the stop point 4.5 m ahead of the front: GEM's a = 3.4 m/s^2, over the 1.8 allowed.
    stop = _stop(_layers(straight_layers))
    stop.update(_cloud([(8.0, -3.2)]), _estimate(speed_mps=5.5), rear_s_m=0.0)
    assert stop.step(0.0, FRONT_M, 5.5) == (None, "")
    assert stop.counters()["gem_sign_too_late"] == 1 and stop.signs == []
    # The same plate seen from 40 m at the same speed (0.42 m/s^2) is stopped for.
    stop.update(_cloud([(40.0, -3.2)]), _estimate(speed_mps=5.5), rear_s_m=0.0)
    assert stop.step(0.0, FRONT_M, 5.5)[0] is not None


def test_the_option_needs_raw_perception_and_a_known_check() -> None:
    with pytest.raises(ConfigError, match=r"stack.gem_sign_stop: expected perception = 'lidar_camera_radar'"):
        StackSettings(perception=PerceptionMode.RADAR_TRACKING, gem_sign_stop=GemSignStopSettings())
    with pytest.raises(ConfigError, match=r"stack.gem_sign_stop.check"):
        GemSignStopSettings(check="every")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"corridor_right_m"):
        GemSignStopSettings(corridor_right_m=0.0)
    with pytest.raises(ConfigError, match=r"max_decel_mps2: expected at least min_decel_mps2"):
        GemSignStopSettings(max_decel_mps2=0.3)
