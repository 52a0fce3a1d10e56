"""The simulator moves the shuttle through the pedal plant whenever a command carries pedals."""

from __future__ import annotations

import pytest

from lastmile.core.pedal_map import brake_decel_mps2
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import ActuatorCommand
from lastmile.runner.closed_loop import load_world_map
from lastmile.sim.scenario import Scenario
from lastmile.sim.simulation import Simulation

TICK_US = 10_000


def _sim() -> Simulation:
    scenario = Scenario(name="pedals", minutes=0.1)
    service = load_world_map(scenario.map)
    return Simulation(scenario, service.hdmap, service.polyline, VehicleGeometry(), TICK_US)


def _cmd(throttle: float | None, brake: float | None, accel: float = 0.0) -> ActuatorCommand:
    return ActuatorCommand(
        stamp=Stamp(0),
        accel_mps2=accel,
        steer_front_rad=0.0,
        steer_rear_rad=0.0,
        throttle=throttle,
        brake=brake,
    )


def test_throttle_drives_and_the_brake_decelerates_by_gems_map() -> None:
    sim = _sim()
    # accel_mps2 says brake hard: only the pedals count on a pedal command.
    for _ in range(300):
        sim.apply_command(_cmd(throttle=1.0, brake=0.0, accel=-3.0))
    state = sim.ego_state
    assert sim.pedal_plant.throttle > 0.99 and state.speed_mps > 1.0
    assert state is sim.pedal_plant.state  # one vehicle, whichever model moves it
    for _ in range(100):  # 1 s on 0.90 (1 m/s^2 on GEM's map): the pedal lags (0.25, 0.15 s) settle
        sim.apply_command(_cmd(throttle=0.0, brake=0.90))
    v0 = state.speed_mps
    for _ in range(100):
        sim.apply_command(_cmd(throttle=0.0, brake=0.90))
    decel = v0 - state.speed_mps  # over 1 s
    d = sim.pedal_plant.dynamics
    drag = d.rolling_decel_mps2 + d.drag_per_m * v0**2
    assert decel == pytest.approx(brake_decel_mps2(0.90) + drag, abs=0.02)


def test_an_acceleration_command_leaves_the_pedal_plant_alone() -> None:
    sim = _sim()
    for _ in range(100):
        sim.apply_command(_cmd(throttle=None, brake=None, accel=1.0))
    assert sim.ego_state.speed_mps > 0.5 and sim.pedal_plant.throttle == 0.0
