"""NUS's control experiment (section V, Figs. 11-12): vehicles on a loop with one pedestrian crossing.

Baseline: without infrastructure, a vehicle must stop at the crossing every lap and look before it
goes (a stop-and-yield sign). With the crossing camera's broadcasts, it keeps moving when the crossing
is reported clear and slows down in anticipation when it is not. Pedestrians arrive as a Poisson
process (lambda = 1 per second); the vehicles keep a minimum gap to the one ahead. The measure is the
time gained per lap, T_gain = T_base - T_infra, summed over laps.

The paper gives neither the loop, the crossing nor the pedestrians' paths; our choices are the
``V2iConfig`` defaults, documented there. Both policies face the same pedestrians (same seed), and
both obey the same rule at the crossing: never enter it while a pedestrian is on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from lastmile.core.config import check_range
from lastmile.core.errors import ConfigError
from lastmile.core.rng import component_rng
from lastmile.sim.infrastructure import CrossingCamera, CrossingCameraConfig

Policy = Literal["baseline", "infrastructure"]


@dataclass(frozen=True, slots=True, kw_only=True)
class V2iConfig:
    """The experiment's world (units in names).

    Attributes:
        loop_m: loop length; the crossing sits at ``crossing_s_m``, ``crossing_width_m`` deep along it.
        pedestrian_rate_per_s: Poisson arrivals at the crossing (NUS: 1 per second).
        crossing_share: share of the arriving pedestrians who cross the road (the others walk along
            the pavement through the camera's view); NUS does not say, we take 0.2.
        pedestrian_speed_mps, road_width_m: a crossing pedestrian blocks the road for width / speed.
        vehicle_length_m, min_gap_m: a golf-car sized vehicle and the gap kept to the one ahead.
        platoon_margin_m: the vehicles start in a platoon, this much beyond the minimum gap apart.
        accel_mps2, decel_mps2: comfortable acceleration and braking.
        look_s: how long the baseline looks, stopped at the line, before it may go.
        onboard_range_m: the vehicle's own sensors see the crossing from this close (both policies).
        dt_s: integration step.
    """

    loop_m: float = 120.0
    crossing_s_m: float = 60.0
    crossing_width_m: float = 4.0
    pedestrian_rate_per_s: float = 1.0
    crossing_share: float = 0.2
    pedestrian_speed_mps: float = 1.3
    road_width_m: float = 4.0
    vehicle_length_m: float = 2.5
    min_gap_m: float = 3.0
    accel_mps2: float = 1.0
    decel_mps2: float = 1.5
    look_s: float = 1.0
    onboard_range_m: float = 8.0
    platoon_margin_m: float = 2.0
    dt_s: float = 0.05
    camera: CrossingCameraConfig = field(default_factory=CrossingCameraConfig)

    def __post_init__(self) -> None:
        check_range("v2i.loop_m", self.loop_m, 20.0, 10_000.0)
        check_range("v2i.crossing_s_m", self.crossing_s_m, 0.0, self.loop_m)
        check_range("v2i.pedestrian_rate_per_s", self.pedestrian_rate_per_s, 0.0, 20.0)
        check_range("v2i.crossing_share", self.crossing_share, 0.0, 1.0)
        check_range("v2i.dt_s", self.dt_s, 0.001, 0.5)


@dataclass(slots=True)
class _Vehicle:
    s_m: float  # front bumper, unwrapped (laps = s // loop)
    v_mps: float = 0.0
    stopped_s: float = 0.0  # how long it has stood at the line (baseline look)
    cleared_lap: int = -1  # the lap whose crossing it has been allowed through
    lap_times_s: list[float] = field(default_factory=list)
    lap_started_s: float = 0.0


def _pedestrian_blocks(config: V2iConfig, laps: int, seed: int) -> np.ndarray:
    """(K, 2) start and end times of crossing pedestrians, long enough for ``laps`` laps."""
    rng = component_rng(seed, "v2i.pedestrians")
    horizon_s = laps * config.loop_m / 0.3 + 600.0  # far beyond the slowest run
    n = rng.poisson(config.pedestrian_rate_per_s * horizon_s)
    starts = np.sort(rng.uniform(0.0, horizon_s, n))
    crossing = rng.random(n) < config.crossing_share
    starts = starts[crossing]
    durations = config.road_width_m / (config.pedestrian_speed_mps * rng.uniform(0.8, 1.2, len(starts)))
    return np.column_stack([starts, starts + durations])


def run_policy(
    config: V2iConfig, policy: Policy, vehicles: int, speed_mps: float, laps: int, seed: int
) -> list[list[float]]:
    """Lap times (s) of each vehicle until every one has done ``laps`` laps."""
    if policy not in ("baseline", "infrastructure"):
        raise ConfigError(f"v2i policy: expected baseline or infrastructure, got {policy!r}")
    if not 1 <= vehicles <= 8:
        raise ConfigError(f"v2i vehicles: expected 1..8, got {vehicles}")
    check_range("v2i.speed_mps", speed_mps, 0.2, 10.0)
    c = config
    # The vehicles start as a platoon (NUS's Fig. 11), each a minimum gap plus a margin behind the
    # one ahead, so that a leader's stop reaches its followers.
    spacing = c.vehicle_length_m + c.min_gap_m + c.platoon_margin_m
    if vehicles * spacing > c.loop_m:
        raise ConfigError(f"v2i: {vehicles} vehicles do not fit on a {c.loop_m} m loop with their gaps")
    fleet = [_Vehicle(s_m=-i * spacing) for i in range(vehicles)]
    blocks = _pedestrian_blocks(c, laps, seed)
    camera = CrossingCamera(c.camera, component_rng(seed, "v2i.camera"))
    t = 0.0
    line_offset = c.crossing_width_m / 2.0 + 0.5  # the stop line, before the crossing
    max_steps = int(laps * c.loop_m / (0.05 * speed_mps) / c.dt_s) + 100_000
    for _ in range(max_steps):
        occupied = _occupied(blocks, t)
        camera.step(t, occupied)
        for i, veh in enumerate(fleet):
            lap = math.floor(veh.s_m / c.loop_m)
            to_line = lap * c.loop_m + c.crossing_s_m - line_offset - veh.s_m
            if to_line < -c.crossing_width_m - c.vehicle_length_m:
                to_line += c.loop_m  # the next crossing is a lap ahead
                lap += 1
            target = speed_mps
            must_stop = _must_stop(c, policy, veh, lap, to_line, occupied, camera, speed_mps)
            if must_stop:
                # Brake to stand at the line; past it (an overshoot) it holds where it is.
                target = min(target, math.sqrt(2.0 * c.decel_mps2 * max(to_line, 0.0)))
            # Keep the gap to the vehicle ahead (the previous one in the list, a lap ahead for the first).
            if vehicles > 1:
                ahead = fleet[i - 1]
                gap = ahead.s_m - veh.s_m - c.vehicle_length_m - c.min_gap_m
                if i == 0:
                    gap += c.loop_m
                # The speed from which it could still stop behind the leader braking as hard (Gipps).
                target = min(target, math.sqrt(ahead.v_mps**2 + 2.0 * c.decel_mps2 * max(gap, 0.0)))
            dv = max(-c.decel_mps2 * c.dt_s * 2.0, min(c.accel_mps2 * c.dt_s, target - veh.v_mps))
            veh.v_mps = max(0.0, veh.v_mps + dv)
            veh.s_m += veh.v_mps * c.dt_s
            if veh.v_mps < 0.05 and -1.0 < to_line < 1.0:
                veh.stopped_s += c.dt_s
            elif to_line < 0.0:
                veh.stopped_s = 0.0
            if veh.s_m >= (len(veh.lap_times_s) + 1) * c.loop_m:
                veh.lap_times_s.append(t + c.dt_s - veh.lap_started_s)
                veh.lap_started_s = t + c.dt_s
        t += c.dt_s
        if all(len(v.lap_times_s) >= laps for v in fleet):
            break
    else:
        raise ConfigError(f"v2i: the {policy} run did not finish {laps} laps; the crossing never cleared")
    return [v.lap_times_s[:laps] for v in fleet]


def _occupied(blocks: np.ndarray, t_s: float) -> bool:
    i = int(np.searchsorted(blocks[:, 0], t_s, side="right"))
    lo = max(0, i - 50)  # crossings last seconds: only recent starts can still be on the road
    return bool(np.any(blocks[lo:i, 1] > t_s))


def _must_stop(
    c: V2iConfig,
    policy: Policy,
    veh: _Vehicle,
    lap: int,
    to_line: float,
    occupied: bool,
    camera: CrossingCamera,
    speed_mps: float,
) -> bool:
    if veh.cleared_lap >= lap:
        return False
    near = to_line <= c.onboard_range_m
    if policy == "baseline":
        # Stop-and-yield: stop at the line every lap, look, and go once the look found it clear.
        if veh.stopped_s >= c.look_s and not occupied:
            veh.cleared_lap = lap
            return False
        return True
    # Infrastructure: go on while the camera reports the crossing clear; slow down (aiming to stop
    # at the line) while it reports pedestrians. Once close, the onboard sensors decide as well.
    report = camera.latest
    reported = report is not None and report.pedestrians_present
    if near and occupied:
        return True
    if near and not occupied and not reported:
        veh.cleared_lap = lap
        return False
    return reported


@dataclass(frozen=True, slots=True, kw_only=True)
class V2iResult:
    """Cumulative time gained per vehicle over laps, by (speed, vehicles): the data of NUS's Fig. 12."""

    laps: int
    seeds: tuple[int, ...]
    rate_hz: float
    cumulative_gain_s: dict[tuple[float, int], list[float]]
    mean_lap_base_s: dict[tuple[float, int], float]
    mean_lap_infra_s: dict[tuple[float, int], float]


def run_v2i_experiment(
    config: V2iConfig | None = None,
    speeds_mps: tuple[float, ...] = (1.0, 2.0),
    vehicle_counts: tuple[int, ...] = (1, 2, 3, 4),
    laps: int = 20,
    seeds: tuple[int, ...] = (0, 1, 2),
) -> V2iResult:
    """Both policies on the same pedestrians, for every speed and fleet size, averaged over seeds.

    ``cumulative_gain_s[(speed, n)][k]`` is T_gain = T_base - T_infra summed over laps 1..k+1, for
    the mean vehicle of an n-vehicle fleet, averaged over ``seeds``.
    """
    c = config or V2iConfig()
    gains: dict[tuple[float, int], list[float]] = {}
    base_mean: dict[tuple[float, int], float] = {}
    infra_mean: dict[tuple[float, int], float] = {}
    for speed in speeds_mps:
        for n in vehicle_counts:
            per_lap = np.zeros(laps)
            base_all, infra_all = [], []
            for seed in seeds:
                base = np.array(run_policy(c, "baseline", n, speed, laps, seed))
                infra = np.array(run_policy(c, "infrastructure", n, speed, laps, seed))
                # Per lap and per vehicle (the fleet's mean), so that a larger fleet gains more only
                # if each of its vehicles does: through the stops a leader's stop forces on it.
                per_lap += (base - infra).mean(axis=0)
                base_all.append(base.mean())
                infra_all.append(infra.mean())
            gains[(speed, n)] = np.cumsum(per_lap / len(seeds)).round(6).tolist()
            base_mean[(speed, n)] = round(float(np.mean(base_all)), 6)
            infra_mean[(speed, n)] = round(float(np.mean(infra_all)), 6)
    return V2iResult(
        laps=laps,
        seeds=seeds,
        rate_hz=c.camera.rate_hz,
        cumulative_gain_s=gains,
        mean_lap_base_s=base_mean,
        mean_lap_infra_s=infra_mean,
    )
