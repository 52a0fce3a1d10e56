"""The simulator assembled from a scenario: world, sensors, riders, referee and operator, in loop phases.

The loop calls the phases in DESIGN.md's order: ``advance_world``, ``sensor_frames``, (the vehicle),
``apply_command``, ``referee``; then ``drain_events`` hands over what the referee and the operators saw.
Road users are added with ``add_road_user``; nothing outside the simulator mutates its lists.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.polyline import Polyline
from lastmile.core.rng import component_rng
from lastmile.core.run_events import EventKind
from lastmile.core.safety_messages import OperatorAction, OperatorInput
from lastmile.core.sensor_frames import SensorFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.core.vehicle_messages import ActuatorCommand, BehaviourState
from lastmile.hdmap.layer_builder import route_crosswalks
from lastmile.hdmap.model import HDMap
from lastmile.hdmap.routing import route, route_polyline
from lastmile.sim.agents import CAR_LENGTH_M, CAR_WIDTH_M, Agent, PathCar, StopLineOnPath, WalkingAgent
from lastmile.sim.drop_offs import DropOffReferee
from lastmile.sim.faults import FaultInjector
from lastmile.sim.judge import Event, Judge
from lastmile.sim.map_traffic import MapTraffic, all_way_stop_lines_on
from lastmile.sim.operator import OperatorModel
from lastmile.sim.operator_estop import EStopAction, OperatorEStop
from lastmile.sim.passengers import PassengerModel
from lastmile.sim.raw_sensors import RawSensorRig
from lastmile.sim.scenario import Scenario
from lastmile.sim.sensors import RCS_DBSM, SensorSuite
from lastmile.sim.throttle_brake import ThrottleBrakeDynamics, ThrottleBrakeVehicle
from lastmile.sim.traffic_light_camera import TrafficLightCameraRig
from lastmile.sim.traffic_signals import SignalController, signal_phases
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState
from lastmile.sim.weather import Weather, parse_weather
from lastmile.sim.world import World

CYCLE_LENGTH_M, CYCLE_WIDTH_M = 1.8, 0.6
LANE_WIDTH_M = 3.5


class Simulation:
    """Ground truth and everything that measures or judges it."""

    def __init__(
        self,
        scenario: Scenario,
        hdmap: HDMap,
        service_route: Polyline,
        geometry: VehicleGeometry,
        tick_us: int,
        raw_sensors: bool = False,
        map_speed_limits: bool = False,
        unmapped_speed_limit_mps: float | None = None,
    ) -> None:
        self.scenario = scenario
        self.tick_us = tick_us
        self.dt_s = tick_us / 1e6
        self.service_route = service_route
        x, y, yaw = service_route.point_at(scenario.start_route_s_m)
        ego = KinematicBicycle(geometry, ActuatorDynamics(), VehicleState(x, y, yaw))
        # A command with pedal positions drives the same vehicle state through the pedal plant.
        self.pedal_plant = ThrottleBrakeVehicle(geometry, ThrottleBrakeDynamics(), ego.state)
        agents = _build_agents(scenario, hdmap, service_route)
        self.world = World(
            hdmap, ego, agents, parse_weather(scenario.weather), component_rng(scenario.seed, "agents")
        )
        self.faults = FaultInjector(scenario.faults, scenario.seed)
        self.sensors = SensorSuite(
            self.world,
            scenario.seed,
            tick_us,
            faults=self.faults,
            gnss_receiver=scenario.gnss.receiver(
                hdmap, service_route, component_rng(scenario.seed, "sensor.gnss.receiver")
            ),
            wheel_slip=scenario.gnss.wheel_slip(self.world.weather is Weather.SNOW),
        )
        # The LiDAR rig and cameras cost ~10 ms per 10 Hz frame: built only when the stack reads them.
        self.raw_sensors = (
            RawSensorRig(self.world, scenario.seed, tick_us, snow_cover_lane_m=scenario.snow_cover_lane_m)
            if raw_sensors
            else None
        )
        self.signals = SignalController(
            scenario.traffic_signals, tuple(s.id for s in hdmap.signals), signal_phases(hdmap)
        )
        self.light_cameras = TrafficLightCameraRig(self.world, self.signals, scenario.seed, tick_us)
        for agent in agents:
            if isinstance(agent, PathCar):
                agent.obey_signals(self.signals, hdmap)
        self.passengers = PassengerModel(
            hdmap.stops,
            scenario.passengers,
            component_rng(scenario.seed, "passengers"),
            geometry.seats,
            drop_off_times_s=tuple(r.t_s for r in scenario.drop_off_requests),
        )
        # On a route map the referee judges the limits the map states (the campus keeps its 20 km/h).
        self.judge = Judge(
            self.world,
            self.passengers,
            service_route,
            signals=self.signals,
            map_speed_limits=map_speed_limits,
            unmapped_speed_limit_mps=unmapped_speed_limit_mps,
        )
        self.operator = OperatorModel(self.judge)
        self.drop_offs = DropOffReferee(self.judge)
        self.estop_operator = OperatorEStop(
            scenario.estop_in_state, scenario.estop_release_s, scenario.estop_min_speed_mps
        )
        self._operator_had_control = False
        self._operator_inputs: list[OperatorInput] = []
        self._events_drained = 0
        self._tick = 0
        self._pending_side_cars = sorted(
            ((c.spawn_t_s, c) for c in scenario.side_road_cars), key=lambda item: item[0]
        )
        self._side_paths = {
            turn: _side_road_path(hdmap, turn) for turn in {c.turn for c in scenario.side_road_cars}
        }
        self._next_id = len(agents) + 1
        self._map_traffic = MapTraffic(scenario.map_cars, hdmap, scenario.seed)

    @property
    def radar_mounts(self) -> dict[str, SE2]:
        """Where the radars sit, which the stack is configured with (as a real vehicle's calibration)."""
        return {r.sensor_id: r.base_from_sensor for r in self.sensors.radars}

    @property
    def ego_state(self) -> VehicleState:
        """The shuttle's true state (for the run log and the referee's side, never for the vehicle)."""
        return self.world.ego.state

    def ego_centre(self) -> tuple[float, float]:
        """The true centre of the shuttle's footprint."""
        return self.world.ego_centre()

    @property
    def map_name(self) -> str:
        return self.world.hdmap.name

    @property
    def route_progress_m(self) -> float:
        """The referee's measure of how far along its route the shuttle is."""
        return self.judge.route_s_m

    @property
    def road_users(self) -> tuple[Agent, ...]:
        """The other road users, as they are (a fleet mirrors one world's pedestrians into the others)."""
        return tuple(self.world.agents)

    def add_road_user(self, agent: Agent) -> None:
        """Put another road user into the world (a fleet's other shuttles, mirrored pedestrians)."""
        self.world.agents.append(agent)

    def drain_events(self) -> list[Event]:
        """The referee's and the operators' events since the last call, in the order they happened."""
        events = self.judge.events
        fresh = events[self._events_drained :]
        self._events_drained = len(events)
        return fresh

    def advance_world(self, tick: int) -> None:
        w = self.world
        self._tick = tick
        w.t_s = tick * self.dt_s
        while self._pending_side_cars and self._pending_side_cars[0][0] <= w.t_s:
            _, spec = self._pending_side_cars.pop(0)
            path, lines = self._side_paths[spec.turn]
            first_line = lines[0].s_m if lines else path.length_m / 2.0
            start_s = max(0.0, first_line - spec.start_m)
            car = _path_car(self._next_id, path, start_s, spec.speed_mps, lines)
            if spec.kind == "cyclist":
                car.cls, car.rcs_dbsm = ObjectClass.CYCLIST, RCS_DBSM[ObjectClass.CYCLIST]
                car.length_m, car.width_m = CYCLE_LENGTH_M, CYCLE_WIDTH_M
                car.max_accel_mps2, car.min_gap_m = 0.8, 1.5
            w.agents.append(car)
            self._next_id += 1
        for car in self._map_traffic.spawn_due(w, self._next_id):
            car.obey_signals(self.signals, self.world.hdmap)
            w.agents.append(car)
            self._next_id += 1
        self.passengers.step_arrivals(w.t_s)
        for stop_id, source in self.passengers.new_calls:
            self.sensors.push_stop_call(tick * self.tick_us, stop_id, source)
        self.passengers.new_calls.clear()
        for passenger_id, seat in self.passengers.press_due(w.t_s):
            self.sensors.push_drop_off(tick * self.tick_us, seat)
            self.drop_offs.requested(passenger_id)
        for agent in w.agents:
            if agent.active or agent.steps_while_away:
                agent.step(w, self.dt_s)
        w.update_intersections()

    def sensor_frames(self, tick: int) -> list[SensorFrame]:
        self.sensors.sample(tick)
        if self.raw_sensors is not None:
            # Raw frames share the suite's delivery queue (latency, faults) with every other sensor.
            for frame, latency_us in self.raw_sensors.sample(tick):
                self.sensors.push(frame, latency_us)
        for frame, latency_us in self.light_cameras.sample(tick):
            self.sensors.push(frame, latency_us)
        frames = self.sensors.deliver(tick * self.tick_us)
        # The operators' inputs of the last tick reach the vehicle with this tick's frames.
        frames.extend(self._operator_inputs)
        self._operator_inputs = []
        return frames

    def apply_command(self, command: ActuatorCommand | None) -> None:
        """Safety gate then vehicle dynamics: the operator's brake overrides the stack while in control.

        A command carrying pedal positions (a throttle/brake vehicle) moves the shuttle through the
        pedal plant (``sim.throttle_brake``); one carrying only an acceleration through the acceleration
        model. Both integrate the same state, so the operator's brake takes over either.
        """
        s = self.world.ego.state
        if self.operator.in_control:
            self.world.ego.step(self.dt_s, -3.0, s.steer_front_rad, s.steer_rear_rad, False)
            door_cmd = False
        elif command is None:
            self.world.ego.step(self.dt_s, -1.5, s.steer_front_rad, s.steer_rear_rad, False)
            door_cmd = False
        elif command.throttle is not None and command.brake is not None:
            self.pedal_plant.step(
                self.dt_s,
                command.throttle,
                command.brake,
                command.steer_front_rad,
                command.steer_rear_rad,
                command.emergency_brake,
            )
            door_cmd = command.door_open
        else:
            self.world.ego.step(
                self.dt_s,
                command.accel_mps2,
                command.steer_front_rad,
                command.steer_rear_rad,
                command.emergency_brake,
            )
            door_cmd = command.door_open
        self._door(door_cmd)

    def _door(self, door_cmd: bool) -> None:
        p, j = self.passengers, self.judge
        stopped = self.world.ego.state.speed_mps < 0.05
        at_stop = j.stop_at() if stopped else None
        was_closed = p.door_position == 0.0
        for kind, data in p.step_door(self.world.t_s, self.dt_s, door_cmd, at_stop, stopped):
            j.emit(kind, **data)
        if was_closed and p.door_position > 0.0 and at_stop is not None and p.visit is None:
            p.visit = j.open_visit(at_stop)
        for passenger_id, stop_id in p.drop_off_alightings:
            self.drop_offs.alighted(passenger_id, stop_id)
        p.drop_off_alightings.clear()
        served = p.end_visit()
        if served is not None:
            j.emit(EventKind.STOP_SERVED, **served)
        self.sensors.door_open = p.door_position > 0.0
        self.sensors.person_in_doorway = p.person_in_doorway

    def referee(self, takeover_request: bool, reported_state: BehaviourState | None = None) -> None:
        """Judge the tick; the safety driver and the e-stop operator act on what they see.

        Args:
            takeover_request: the vehicle asks for a takeover.
            reported_state: the behaviour state the vehicle shows (the e-stop operator presses in one).
        """
        self.judge.step()
        self.drop_offs.step()
        self.operator.step(takeover_request, self.passengers.door_position > 0.0)
        now = Stamp(self._tick * self.tick_us)
        # The safety driver handing back is the operator's reset of a latched emergency stop.
        if self._operator_had_control and not self.operator.in_control:
            self._operator_inputs.append(OperatorInput(stamp=now, action=OperatorAction.RESET))
        self._operator_had_control = self.operator.in_control
        # The operator's timer counts in the loop's integer microseconds (tick * dt_s rounds differently).
        t_s = self._tick * self.tick_us / 1e6
        action = self.estop_operator.step(t_s, reported_state, self.world.ego.state.speed_mps)
        state = self.scenario.estop_in_state
        if action == EStopAction.PRESS:
            reason = f"operator e-stop in {state}"
            self._operator_inputs.append(
                OperatorInput(stamp=now, action=OperatorAction.EMERGENCY_STOP, reason=reason)
            )
            self.judge.emit(EventKind.OPERATOR_ESTOP, state=state)
        elif action == EStopAction.RELEASE:
            self._operator_inputs.append(OperatorInput(stamp=now, action=OperatorAction.RESET))
            self.judge.emit(EventKind.OPERATOR_RELEASE, state=state)


def _path_car(
    agent_id: int, path: Polyline, s_m: float, speed_mps: float, lines: list[StopLineOnPath]
) -> PathCar:
    x, y, yaw = path.point_at(s_m)
    return PathCar(
        id=agent_id,
        cls=ObjectClass.CAR,
        x_m=x,
        y_m=y,
        yaw_rad=yaw,
        speed_mps=speed_mps,
        length_m=CAR_LENGTH_M,
        width_m=CAR_WIDTH_M,
        rcs_dbsm=RCS_DBSM[ObjectClass.CAR],
        path=path,
        s_m=s_m,
        desired_speed_mps=speed_mps,
        stop_lines=[StopLineOnPath(s_m=line.s_m, stop_line_id=line.stop_line_id) for line in lines],
        despawn_at_end=not path.closed,
    )


def _side_road_path(hdmap: HDMap, turn: str) -> tuple[Polyline, list[StopLineOnPath]]:
    """Side road northbound from its far end, through the all-way stop, turning onto the ring."""
    start = _lanelet_heading(hdmap, (381.75, -120.0), math.pi / 2) or _lanelet_heading(
        hdmap, (378.25, -120.0), math.pi / 2
    )
    goal = (
        _lanelet_heading(hdmap, (300.0, 1.75), math.pi)
        if turn == "left"
        else _lanelet_heading(hdmap, (460.0, -1.75), 0.0)
    )
    if start is None or goal is None:
        raise ConfigError(
            f"side_road_cars: expected the campus map's side road and ring lanes, not found for {turn!r}"
        )
    path = route_polyline(hdmap, route(hdmap, start, goal))
    return path, all_way_stop_lines_on(path, hdmap)


def _lanelet_heading(hdmap: HDMap, xy: tuple[float, float], heading_rad: float) -> int | None:
    lid = hdmap.lanelet_at(*xy)
    if lid is None:
        return None
    centre = hdmap.lanelets[lid].centerline
    f = centre.project(*xy)
    return lid if math.cos(centre.heading_at(f.s_m) - heading_rad) > 0.7 else None


def _build_agents(scenario: Scenario, hdmap: HDMap, service_route: Polyline) -> list[Agent]:
    agents: list[Agent] = []
    ccw_lines = all_way_stop_lines_on(service_route, hdmap)
    cw_path = Polyline(service_route.offset(LANE_WIDTH_M).xy_m[::-1].copy(), closed=True)
    cw_lines = all_way_stop_lines_on(cw_path, hdmap)
    for car in scenario.ring_cars:
        if car.direction == "ccw":
            agents.append(_path_car(len(agents) + 1, service_route, car.start_s_m, car.speed_mps, ccw_lines))
        else:
            agents.append(_path_car(len(agents) + 1, cw_path, car.start_s_m, car.speed_mps, cw_lines))
    stops = {s.id: s for s in hdmap.stops}
    for parked in scenario.parked_cars:
        if parked.stop not in stops:
            raise ConfigError(f"parked_cars.stop: expected one of {sorted(stops)}, got {parked.stop!r}")
        curb = stops[parked.stop].curb
        along = curb.length_m - parked.from_end_m - CAR_LENGTH_M / 2.0
        x, y, yaw = curb.point_at(along)
        off = 0.2 + CAR_WIDTH_M / 2.0
        agents.append(
            Agent(
                id=len(agents) + 1,
                cls=ObjectClass.CAR,
                x_m=x - off * math.sin(yaw),
                y_m=y + off * math.cos(yaw),
                yaw_rad=yaw,
                speed_mps=0.0,
                length_m=CAR_LENGTH_M,
                width_m=CAR_WIDTH_M,
                rcs_dbsm=RCS_DBSM[ObjectClass.CAR],
            )
        )
    for obstacle in scenario.static_obstacles:
        x, y, yaw = service_route.point_at(obstacle.route_s_m)
        cls = ObjectClass.CAR if obstacle.kind == "car" else ObjectClass.UNKNOWN
        agents.append(
            Agent(
                id=len(agents) + 1,
                cls=cls,
                x_m=x - obstacle.d_m * math.sin(yaw),
                y_m=y + obstacle.d_m * math.cos(yaw),
                yaw_rad=yaw,
                speed_mps=0.0,
                length_m=obstacle.length_m,
                width_m=obstacle.width_m,
                rcs_dbsm=RCS_DBSM[cls],
            )
        )
    groups = list(scenario.crosswalk_pedestrians)
    if scenario.route_crosswalk_pedestrians is not None:
        at = scenario.route_crosswalk_pedestrians
        ids = [cw.id for cw in hdmap.crosswalks]
        on_route = sorted({ids.index(rc.crosswalk.id) for rc in route_crosswalks(hdmap, service_route)})
        groups += [dataclasses.replace(at, crosswalk=k) for k in on_route]
    for group in groups:
        if not 0 <= group.crosswalk < len(hdmap.crosswalks):
            raise ConfigError(
                "crosswalk_pedestrians.crosswalk: expected "
                f"0..{len(hdmap.crosswalks) - 1}, got {group.crosswalk}"
            )
        centre = np.asarray(hdmap.crosswalks[group.crosswalk].polygon, dtype=float).mean(axis=0)
        f = service_route.project(float(centre[0]), float(centre[1]))
        start, end = _crossing(service_route, f.s_m, from_left=False)
        agents.append(
            _walker(
                len(agents) + 1,
                ObjectClass.PEDESTRIAN,
                start,
                end,
                group.speed_mps,
                3.5,
                respawn=True,
                start_after_s=group.first_after_s,
                mean_gap_s=group.mean_gap_s,
                approach_m=group.approach_m,
            )
        )
    for walker in scenario.walkers:
        start, end = _crossing(service_route, walker.route_s_m, walker.from_left)
        cls = ObjectClass.ANIMAL if walker.kind == "goose" else ObjectClass.PEDESTRIAN
        agent = _walker(len(agents) + 1, cls, start, end, walker.speed_mps, walker.gap_s)
        agent.trigger_distance_m = walker.trigger_m
        agent.min_trigger_distance_m = walker.min_trigger_m
        if cls == ObjectClass.ANIMAL:
            agent.pause_every_m, agent.pause_s = 1.5, 2.0  # geese stop and peck on the way
        agents.append(agent)
    return agents


def _crossing(
    route_: Polyline, s_m: float, from_left: bool
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Kerb-to-kerb crossing points at route s: the road spans d in [-1.75, +5.25] from the lane centre."""
    x, y, h = route_.point_at(s_m)
    nx, ny = -math.sin(h), math.cos(h)
    left = (x + 6.5 * nx, y + 6.5 * ny)
    right = (x - 3.0 * nx, y - 3.0 * ny)
    return (left, right) if from_left else (right, left)


def _walker(
    agent_id: int,
    cls: ObjectClass,
    start: tuple[float, float],
    end: tuple[float, float],
    speed_mps: float,
    gap_s: float,
    respawn: bool = False,
    start_after_s: float = 0.0,
    mean_gap_s: float = 30.0,
    approach_m: float = 0.0,
) -> WalkingAgent:
    small = cls == ObjectClass.ANIMAL
    return WalkingAgent(
        id=agent_id,
        cls=cls,
        x_m=start[0],
        y_m=start[1],
        yaw_rad=math.atan2(end[1] - start[1], end[0] - start[0]),
        speed_mps=0.0,
        length_m=0.5,
        width_m=0.3 if small else 0.5,
        rcs_dbsm=RCS_DBSM[cls],
        start_xy=start,
        end_xy=end,
        walk_speed_mps=speed_mps,
        gap_s=gap_s,
        respawn=respawn,
        start_after_s=start_after_s,
        mean_gap_s=mean_gap_s,
        approach_m=approach_m,
    )
