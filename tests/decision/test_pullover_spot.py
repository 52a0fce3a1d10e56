from lastmile.core.object_class import ObjectClass
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.decision.pullover_spot import SpotRequest, choose_spot

REQ = SpotRequest(
    platform_start_s_m=200.0,
    platform_end_s_m=224.0,
    bay_edge_d_m=-1.75,
    curb_d_m=-4.75,
    vehicle_length_m=4.6,
    transition_m=8.0,
    margin_m=3.5,
    preferred_front_s_m=214.3,
)


def _parked(s_m: float, d_m: float = -3.3) -> RouteObstacle:
    return RouteObstacle(1, ObjectClass.CAR, s_m, d_m, s_m, 0.0, d_m, 0.0, 0.0, 4.5, 1.8)


def test_empty_stop_gives_the_preferred_spot():
    spot = choose_spot(REQ, [])
    assert spot is not None and abs(spot - REQ.preferred_front_s_m) <= 0.25  # half the 0.5 m scan step


def test_parked_car_at_the_platform_end_moves_the_spot_behind_it_with_margin():
    spot = choose_spot(REQ, [_parked(220.0)])
    assert spot is not None
    assert spot <= 220.0 - 2.25 - 3.5
    assert spot - 4.6 >= 200.0


def test_stop_full_of_obstacles_has_no_spot():
    assert choose_spot(REQ, [_parked(204.0), _parked(214.0), _parked(222.0)]) is None


def test_traffic_in_the_lane_and_people_beyond_the_curb_do_not_block_the_bay():
    in_lane = _parked(214.0, d_m=0.0)
    on_platform = RouteObstacle(2, ObjectClass.PEDESTRIAN, 214.0, -6.0, 214.0, 0.0, -6.0, 0.0, 0.0, 0.5, 0.5)
    assert choose_spot(REQ, [in_lane, on_platform]) == choose_spot(REQ, [])
