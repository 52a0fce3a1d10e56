"""Raw sensors on the straight test road with nobody on it: no track is published and nothing is braked
for, up to and over the crosswalk (issue #22's phantom tracks).

The road has no mapped curbs: the simulator raises everything beside the 3.5 m lane 0.15 m (a sidewalk
without a curb line for the curb-side stage to recognise), which is where the phantoms came from: the
right curb's obstacle reassignment reached the far sidewalk, and sidewalk returns inside the map's road
edge stood out of the road plane. Both stood still beside the shuttle, so they were tracked moving at its
speed, and the crosswalk rule stopped the shuttle for them.
"""

from __future__ import annotations

import itertools

import pytest

from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import StopReason
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.runner.closed_loop import sensor_calibration
from lastmile.runner.loop import ClosedLoop
from lastmile.runner.run_config import RunConfig
from lastmile.sim.passengers import PassengerConfig
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation
from lastmile.stack.vehicle_build import build_vehicle

pytestmark = pytest.mark.closed_loop

START_X_M = 80.0  # the crosswalk (x 98-102) lies 18 m ahead
SECONDS = 9.0


def test_no_track_is_published_and_nothing_braked_for_on_an_empty_road(
    straight_layers: SLayerDatabase,
) -> None:
    config = RunConfig()  # the default: raw LiDAR, camera and radar
    assert config.stack.perception.needs_raw_sensors
    scenario = Scenario(
        name="empty_straight_road",
        minutes=SECONDS / 60.0,
        start_route_s_m=START_X_M,
        passengers=PassengerConfig(arrivals_per_stop_per_min=0.0),
    )
    geometry = VehicleGeometry()
    tick_us = config.loop.tick_us
    world = Simulation(
        scenario, straight_layers.hdmap, straight_layers.centerline, geometry, tick_us, raw_sensors=True
    )
    vehicle = build_vehicle(straight_layers, geometry, config.stack, sensor_calibration(world), tick_us)
    stack = vehicle.software
    loop = ClosedLoop(world, stack, vehicle.safety, tick_us)
    published, reasons, speeds = [], set(), []
    for record in loop.ticks(round(SECONDS * 1e6 / tick_us)):
        out = record.output
        assert out is not None, record.failure
        if out.decision is not None:
            published.append(len(stack._tracks))
            reasons.add(out.decision.stop_reason)
            speeds.append(world.world.ego.state.speed_mps)
    raw = stack.raw
    assert raw is not None and raw.stats.rig_frames >= 10 * (SECONDS - 1.0)
    assert max(published) == 0
    assert reasons == {StopReason.NONE}
    # Never slowed down: the speed only grows until the cruise speed, then holds it.
    assert all(b >= a - 0.05 for a, b in itertools.pairwise(speeds))
    assert world.world.ego.state.x_m > 100.0  # over the crosswalk
