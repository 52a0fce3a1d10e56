"""Sensor models: what the shuttle's real sensors would output, with noise, limits and latency.

Each sensor samples ground truth at its own rate (an integer number of base ticks) and its frame is
delivered to the stack after the sensor's latency, so frames from different sensors can arrive out
of capture order, as they do on the vehicle.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.geometry import SE2
from lastmile.core.gnss_messages import GnssQuality
from lastmile.core.object_class import ObjectClass
from lastmile.core.rng import component_rng
from lastmile.core.sensor_frames import (
    DoorSensorFrame,
    DropOffRequestFrame,
    GnssInsFrame,
    ImuFrame,
    RadarFrame,
    SensorFrame,
    StopCallFrame,
    WheelOdometryFrame,
)
from lastmile.core.stamp import Stamp
from lastmile.sim.agents import agent_arrays
from lastmile.sim.faults import FaultInjector
from lastmile.sim.gnss_degradation import GnssDegradation, WheelSlip
from lastmile.sim.weather import Weather
from lastmile.sim.world import World

# What a receiver without a fix reports as its accuracy: it keeps sending its dead-reckoned guess.
NO_FIX_STD_M = 10.0

# A 4-bit alive counter, as CAN end-to-end protection uses (AUTOSAR E2E profile 1).
ODOM_CYCLE_MODULO = 16


@dataclass(frozen=True, slots=True, kw_only=True)
class RadarSpec:
    """A radar's mounting (on the base frame: rear axle, x forward) and performance in clear weather."""

    sensor_id: str
    base_from_sensor: SE2
    period_ticks: int = 5
    latency_us: int = 60_000
    max_range_m: float = 70.0
    half_fov_rad: float = math.radians(75.0)
    pos_std_m: float = 0.12
    pos_std_per_m: float = 0.004
    vel_std_mps: float = 0.12
    # Mean raw reflections per cycle from the static scene (road surface, curbs, poles, facades) in
    # clear weather; objects come on top. Only their count leaves the radar (see RadarFrame).
    static_clutter_per_cycle: float = 40.0


def default_radars(front_from_rear_axle_m: float, rear_overhang_m: float) -> tuple[RadarSpec, ...]:
    """Front and rear radars at the bumpers, as WATonoBus mounts them."""
    return (
        RadarSpec(
            sensor_id="front", base_from_sensor=SE2(front_from_rear_axle_m, 0.0, 0.0), max_range_m=100.0
        ),
        RadarSpec(
            sensor_id="rear",
            base_from_sensor=SE2(-rear_overhang_m, 0.0, math.pi),
            latency_us=45_000,
            max_range_m=60.0,
        ),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorRates:
    """Periods in base ticks (10 ms) and latencies of the non-radar sensors."""

    gnss_period_ticks: int = 10
    gnss_latency_us: int = 30_000
    gnss_pos_std_m: float = 0.02
    gnss_yaw_std_rad: float = 0.004
    imu_period_ticks: int = 2
    imu_latency_us: int = 4_000
    imu_yaw_rate_std_radps: float = 0.003
    odom_period_ticks: int = 2
    odom_latency_us: int = 8_000
    door_period_ticks: int = 10
    door_latency_us: int = 20_000
    v2i_latency_us: int = 200_000


def detection_probability(rcs_dbsm: float, range_m: float, max_range_m: float) -> float:
    """Chance a real object shows in one radar frame, from its RCS and range (clear weather).

    Small targets fade well before the radar's maximum range: a radar sees a -15 dBsm goose only
    within a few tens of metres.
    """
    # Effective range for this RCS: every 10 dB less RCS shortens it by ~44 % (fourth-root law).
    reach = max_range_m * 10.0 ** ((min(rcs_dbsm, 10.0) - 10.0) / 40.0)
    if range_m > reach:
        return 0.0
    base = 0.97 if rcs_dbsm >= 0 else (0.92 if rcs_dbsm >= -10 else 0.85)
    return base * (1.0 - 0.4 * (range_m / reach) ** 4)


@dataclass(order=True)
class _Pending:
    deliver_us: int
    seq: int
    frame: SensorFrame = field(compare=False)


class SensorSuite:
    """Samples every sensor at its rate and hands frames over once their latency has elapsed."""

    def __init__(
        self,
        world: World,
        seed: int,
        tick_us: int,
        radars: tuple[RadarSpec, ...] | None = None,
        rates: SensorRates | None = None,
        faults: FaultInjector | None = None,
        gnss_receiver: GnssDegradation | None = None,
        wheel_slip: WheelSlip | None = None,
    ) -> None:
        """Args:
        gnss_receiver: the degraded receiver of the scenario's ``[gnss]`` table (None: plain RTK).
        wheel_slip: wheel slip on snow (None: the weather's slip noise only).
        """
        self.world = world
        self.gnss_receiver = gnss_receiver
        self.wheel_slip = wheel_slip
        # Own streams, so that turning degradation on leaves every other draw as it was.
        self._slip_rng = component_rng(seed, "sensor.odom.slip")
        self.tick_us = tick_us
        g = world.geometry
        self.radars = radars or default_radars(g.front_from_rear_axle_m, g.rear_overhang_m)
        self.rates = rates or SensorRates()
        self._rng = {
            name: component_rng(seed, f"sensor.{name}")
            for name in ("gnss", "imu", "odom", "door", *(r.sensor_id for r in self.radars))
        }
        # Separate streams, so adding the clutter count left every other draw as it was.
        self._clutter_rng = {
            r.sensor_id: component_rng(seed, f"sensor.{r.sensor_id}.clutter") for r in self.radars
        }
        self._odom_cycle = -1
        self.faults = faults
        self._pending: list[_Pending] = []
        self._seq = 0
        self._radar_cycles: dict[str, int] = {}
        self._odom_scale = 1.0 + float(self._rng["odom"].normal(0.0, 0.003))
        self.door_open = False
        self.person_in_doorway = False

    def push(self, frame: SensorFrame, latency_us: int) -> None:
        """Queue ``frame`` for delivery ``latency_us`` after its stamp, through the fault injector
        (also frames captured by sensor models outside the suite: the raw rig, light cameras)."""
        if self.faults is None:
            delivered = [(frame, latency_us)]
        else:
            delivered = self.faults.capture(frame, latency_us, int(frame.stamp) / 1e6)
        for out, latency in delivered:
            self._seq += 1
            heapq.heappush(self._pending, _Pending(int(out.stamp) + latency, self._seq, out))

    def push_stop_call(self, now_us: int, stop_id: str, source: str) -> None:
        """A stop button or seat button press, carried over V2I / the vehicle bus."""
        self.push(
            StopCallFrame(stamp=Stamp(now_us), stop_id=stop_id, source=source), self.rates.v2i_latency_us
        )

    def push_drop_off(self, now_us: int, seat: int) -> None:
        """A seat's drop-off button, on the vehicle's own bus (the door sensor's latency)."""
        self.push(DropOffRequestFrame(stamp=Stamp(now_us), seat=seat), self.rates.door_latency_us)

    def sample(self, tick: int) -> None:
        """Capture every sensor due at ``tick``."""
        now = Stamp(tick * self.tick_us)
        r = self.rates
        if tick % r.gnss_period_ticks == 0:
            self.push(self._gnss(now), r.gnss_latency_us)
        if tick % r.imu_period_ticks == 0:
            self.push(self._imu(now), r.imu_latency_us)
        if tick % r.odom_period_ticks == 0:
            self.push(self._odom(now), r.odom_latency_us)
        if tick % r.door_period_ticks == 0:
            self.push(
                DoorSensorFrame(
                    stamp=now, door_open=self.door_open, person_in_doorway=self.person_in_doorway
                ),
                r.door_latency_us,
            )
        agents = None
        for spec in self.radars:
            if tick % spec.period_ticks == 0:
                if agents is None:
                    agents = agent_arrays(self.world.agents)
                self.push(self._radar(now, spec, agents), spec.latency_us)

    def deliver(self, now_us: int) -> list[SensorFrame]:
        """Frames whose latency has elapsed by ``now_us``, in delivery order."""
        out: list[SensorFrame] = []
        while self._pending and self._pending[0].deliver_us <= now_us:
            out.append(heapq.heappop(self._pending).frame)
        return out

    def _gnss(self, now: Stamp) -> GnssInsFrame:
        if self.gnss_receiver is not None:
            return self._degraded_gnss(now, self.gnss_receiver)
        s, rng, r = self.world.ego.state, self._rng["gnss"], self.rates
        std = r.gnss_pos_std_m * self.world.effects.gnss_noise_factor
        return GnssInsFrame(
            stamp=now,
            x_m=s.x_m + float(rng.normal(0.0, std)),
            y_m=s.y_m + float(rng.normal(0.0, std)),
            yaw_rad=s.yaw_rad + float(rng.normal(0.0, r.gnss_yaw_std_rad)),
            speed_mps=max(0.0, s.speed_mps + float(rng.normal(0.0, 0.02))),
            pos_std_m=std,
            yaw_std_rad=r.gnss_yaw_std_rad,
        )

    def _degraded_gnss(self, now: Stamp, receiver: GnssDegradation) -> GnssInsFrame:
        """The receiver's solution: its quality and reported sigma, or its no-fix guess in an outage."""
        s, rng, r = self.world.ego.state, self._rng["gnss"], self.rates
        fix = receiver.fix(now, s.x_m, s.y_m, heavy_snow=self.world.weather is Weather.SNOW)
        yaw = s.yaw_rad + float(rng.normal(0.0, r.gnss_yaw_std_rad))
        speed = max(0.0, s.speed_mps + float(rng.normal(0.0, 0.02)))
        if fix is None:
            # No fix: the receiver's dead-reckoned guess, metres off, and flagged as such.
            return GnssInsFrame(
                stamp=now,
                x_m=s.x_m + float(rng.normal(0.0, NO_FIX_STD_M)),
                y_m=s.y_m + float(rng.normal(0.0, NO_FIX_STD_M)),
                yaw_rad=yaw,
                speed_mps=speed,
                pos_std_m=NO_FIX_STD_M,
                yaw_std_rad=r.gnss_yaw_std_rad,
                fix_ok=False,
                quality=GnssQuality.SINGLE,
            )
        return GnssInsFrame(
            stamp=now,
            x_m=fix.x_m,
            y_m=fix.y_m,
            yaw_rad=yaw,
            speed_mps=speed,
            pos_std_m=float(np.sqrt(max(fix.var_xx_m2, fix.var_yy_m2))),
            yaw_std_rad=r.gnss_yaw_std_rad,
            quality=fix.quality,
        )

    def _imu(self, now: Stamp) -> ImuFrame:
        s, rng = self.world.ego.state, self._rng["imu"]
        return ImuFrame(
            stamp=now,
            yaw_rate_radps=s.yaw_rate_radps + float(rng.normal(0.0, self.rates.imu_yaw_rate_std_radps)),
            accel_x_mps2=s.accel_mps2 + float(rng.normal(0.0, 0.05)),
            accel_y_mps2=s.speed_mps * s.yaw_rate_radps + float(rng.normal(0.0, 0.05)),
        )

    def _odom(self, now: Stamp) -> WheelOdometryFrame:
        s, rng = self.world.ego.state, self._rng["odom"]
        slip = float(rng.normal(0.0, self.world.effects.wheel_slip_std)) if s.speed_mps > 0 else 0.0
        self._odom_cycle = (self._odom_cycle + 1) % ODOM_CYCLE_MODULO
        speed = max(0.0, s.speed_mps * (self._odom_scale + slip))
        if self.wheel_slip is not None:
            speed = max(0.0, self.wheel_slip.corrupt(speed, self._slip_rng))
        return WheelOdometryFrame(
            stamp=now,
            speed_mps=speed,
            steer_front_rad=s.steer_front_rad,
            steer_rear_rad=s.steer_rear_rad,
            cycle=self._odom_cycle,
        )

    def _radar(self, now: Stamp, spec: RadarSpec, agents: np.ndarray) -> RadarFrame:
        s, rng, fx = self.world.ego.state, self._rng[spec.sensor_id], self.world.effects
        map_from_sensor = SE2(s.x_m, s.y_m, s.yaw_rad).compose(spec.base_from_sensor)
        c, si = math.cos(map_from_sensor.yaw_rad), math.sin(map_from_sensor.yaw_rad)
        max_range = spec.max_range_m * fx.radar_range_factor
        rows: list[tuple[float, float, float, float, float, float]] = []
        if len(agents):
            dx = agents[:, 0] - map_from_sensor.x_m
            dy = agents[:, 1] - map_from_sensor.y_m
            # The radar reports the reflection centre, which for a box is nearer than its centre.
            rng_c = np.hypot(dx, dy)
            xs = c * dx + si * dy
            ys = -si * dx + c * dy
            az = np.arctan2(ys, xs)
            half_extent = 0.5 * np.minimum(agents[:, 5], agents[:, 6])
            ranges = np.maximum(rng_c - half_extent, 0.3)
            visible = (np.abs(az) <= spec.half_fov_rad) & (ranges <= max_range)
            order = np.argsort(ranges)
            shadows: list[tuple[float, float]] = []
            for i in order:
                if not visible[i]:
                    continue
                mid_rad, half_width_rad = _bearing_span(
                    xs[i], ys[i], float(agents[i, 2]) - map_from_sensor.yaw_rad, agents[i, 5], agents[i, 6]
                )
                p = detection_probability(agents[i, 8], ranges[i], max_range) * fx.radar_detect_factor
                # Something nearer in the same direction masks most of the return.
                if any(abs(mid_rad - a0) < w0 + half_width_rad * 0.5 for a0, w0 in shadows):
                    p *= 0.3
                shadows.append((mid_rad, half_width_rad))
                if rng.random() >= p:
                    continue
                noise = (spec.pos_std_m + spec.pos_std_per_m * ranges[i]) * fx.radar_noise_factor
                scale = ranges[i] / max(rng_c[i], 1e-6)
                px = xs[i] * scale + float(rng.normal(0.0, noise))
                py = ys[i] * scale + float(rng.normal(0.0, noise))
                vx_map, vy_map = agents[i, 3], agents[i, 4]
                vx = (
                    c * vx_map
                    + si * vy_map
                    + float(rng.normal(0.0, spec.vel_std_mps * fx.radar_noise_factor))
                )
                vy = (
                    -si * vx_map
                    + c * vy_map
                    + float(rng.normal(0.0, spec.vel_std_mps * fx.radar_noise_factor))
                )
                rcs = agents[i, 8] + float(rng.normal(0.0, 2.0))
                rr = _range_rate(px, py, vx, vy, spec, s.speed_mps)
                rows.append((px, py, vx, vy, rcs, rr))
        for _ in range(int(rng.poisson(fx.radar_false_alarms_per_frame))):
            r_fa = float(rng.uniform(2.0, min(40.0, max_range)))
            a_fa = float(rng.uniform(-spec.half_fov_rad, spec.half_fov_rad))
            px, py = r_fa * math.cos(a_fa), r_fa * math.sin(a_fa)
            vx, vy = float(rng.normal(0.0, 0.5)), float(rng.normal(0.0, 0.5))
            rows.append(
                (
                    px,
                    py,
                    vx,
                    vy,
                    float(rng.uniform(-20.0, -5.0)),
                    _range_rate(px, py, vx, vy, spec, s.speed_mps),
                )
            )
        cycle = self._radar_cycles.get(spec.sensor_id, -1) + 1
        self._radar_cycles[spec.sensor_id] = cycle
        clutter = int(
            self._clutter_rng[spec.sensor_id].poisson(spec.static_clutter_per_cycle * fx.radar_range_factor)
        )
        return RadarFrame(
            stamp=now,
            sensor_id=spec.sensor_id,
            objects=np.array(rows, dtype=np.float64).reshape(-1, 6),
            cycle=cycle,
            raw_detections=len(rows) + clutter,
        )


def _range_rate(px: float, py: float, vx: float, vy: float, spec: RadarSpec, ego_speed_mps: float) -> float:
    """Doppler: relative velocity along the line of sight (the radar's own motion included)."""
    c = math.cos(spec.base_from_sensor.yaw_rad)
    rel_vx = vx - ego_speed_mps * c
    r = math.hypot(px, py)
    return (px * rel_vx + py * vy) / max(r, 1e-6)


# Radar cross-sections (dBsm) by class, typical 77 GHz values.
RCS_DBSM = {
    ObjectClass.UNKNOWN: 0.0,  # a box, barrel or fallen load: between a pedestrian and a car
    ObjectClass.CAR: 10.0,
    ObjectClass.PEDESTRIAN: -5.0,
    ObjectClass.CYCLIST: -2.0,
    ObjectClass.ANIMAL: -15.0,
}


def _bearing_span(
    x_m: float, y_m: float, yaw_rad: float, length_m: float, width_m: float
) -> tuple[float, float]:
    """Middle and half-width (rad) of the bearings a box (centre (x, y) and yaw in the sensor frame)
    spans as seen from the sensor: its outline, not its longest side (a car seen from behind at 15 m
    spans 3.4 deg either way, not the 8.5 deg its length would give; that hid the whole oncoming lane
    beyond a parked car from a shuttle waiting to pass it)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    bearings = [
        math.atan2(y_m + a * s + b * c, x_m + a * c - b * s)
        for a in (-0.5 * length_m, 0.5 * length_m)
        for b in (-0.5 * width_m, 0.5 * width_m)
    ]
    lo, hi = min(bearings), max(bearings)
    if hi - lo > math.pi:  # straddles the sensor's back: take the full outline's reach
        return math.atan2(y_m, x_m), math.pi / 2.0
    return 0.5 * (lo + hi), 0.5 * (hi - lo)
