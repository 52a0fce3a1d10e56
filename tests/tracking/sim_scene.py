"""Simulated radar scenes for aUToTrack's arrival-order tests and ``benchmarks/tracking_sim.py``.

The shuttle stands 20 m before the campus loop's first crosswalk while cars pass in both directions
(some queue behind it) and pedestrians cross. Four radars stamp their frames at different times (20, 16.7,
14.3 and 12.5 Hz). Each frame arrives after a random latency (up to 300 ms): ``shuffled`` hands
frames over as they arrive (frames of different radars, and consecutive frames of one radar, out of
capture order); ``ordered`` hands them over in capture order (see :func:`deliveries`).
Every 100 ms the tracks the tracker publishes for that instant are scored against the
simulator's ground truth (evaluation may read it; the tracker never does).

The ego pose used to bring radar objects into the map frame is the simulator's (the shuttle stands still;
localisation is not what is measured here). Optionally the three simulated LiDARs feed
:class:`~lastmile.perception.pipeline.LidarPipeline` and its clusters join as a fifth source (fusion
happens in the tracker: LiDAR boxes carry shape, radar boxes the Doppler velocity).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment

from lastmile.core.boxes3d import DetectedBoxes, TrackedBoxes
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.rng import component_rng
from lastmile.core.sensor_frames import LidarSweep, RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.perception.pipeline import LidarPipeline, LidarPipelineResult
from lastmile.runner.loop import parked_ticks
from lastmile.sim.lidar_rig import LidarSpec
from lastmile.sim.raw_sensors import RawSensorRig
from lastmile.sim.scenario import CrosswalkPedestrians, RingCar, Scenario, SideRoadCar, Walker
from lastmile.sim.sensors import RadarSpec, SensorSuite
from lastmile.sim.simulation import Simulation
from lastmile.tracking.autotrack import AutoTrack, AutoTrackConfig

TICK_US = 10_000
EVAL_PERIOD_US = 100_000
MAX_LATENCY_US = 300_000
SCENE_RANGE_M = 50.0
MATCH_GATE_M = 3.0
# Footprint (length, width, height) given to a radar object of each class: radar has no extent.
RADAR_BOX_SIZE = {
    ObjectClass.CAR: (4.5, 1.8, 1.5),
    ObjectClass.PEDESTRIAN: (0.6, 0.6, 1.7),
    ObjectClass.CYCLIST: (1.8, 0.6, 1.7),
    ObjectClass.ANIMAL: (0.6, 0.4, 0.6),
}


def scene(seed: int, seconds: float, weather: str) -> Scenario:
    """Traffic and pedestrians around a standing shuttle at the first crosswalk (route s = 110 m)."""
    return Scenario(
        name="tracking_sim",
        minutes=seconds / 60.0,
        seed=seed,
        weather=weather,
        start_route_s_m=110.0,
        ring_cars=(
            # Oncoming on the other lane (its s runs the other way round the 2022 m loop): they pass.
            RingCar(direction="cw", start_s_m=1840.0, speed_mps=5.0),
            RingCar(direction="cw", start_s_m=1860.0, speed_mps=6.0),
            RingCar(direction="cw", start_s_m=1885.0, speed_mps=5.0),
            RingCar(direction="cw", start_s_m=1920.0, speed_mps=6.0),
            RingCar(direction="cw", start_s_m=1960.0, speed_mps=5.0),
            # In the shuttle's lane: one drives away ahead, two close up behind and queue.
            RingCar(direction="ccw", start_s_m=135.0, speed_mps=5.0),
            RingCar(direction="ccw", start_s_m=75.0, speed_mps=5.0),
            RingCar(direction="ccw", start_s_m=45.0, speed_mps=6.0),
        ),
        side_road_cars=(SideRoadCar(spawn_t_s=5.0, turn="left"),),
        crosswalk_pedestrians=(
            CrosswalkPedestrians(crosswalk=0, mean_gap_s=3.0, first_after_s=0.5, approach_m=6.0),
        ),
        walkers=(Walker(kind="pedestrian", route_s_m=140.0, trigger_m=45.0, min_trigger_m=10.0),),
    )


def radar_rig(front_m: float, rear_overhang_m: float) -> tuple[RadarSpec, ...]:
    """Front, rear and two front-corner radars with different periods, so their stamps differ."""
    return (
        RadarSpec(
            sensor_id="front", base_from_sensor=SE2(front_m, 0.0, 0.0), period_ticks=5, max_range_m=100.0
        ),
        RadarSpec(sensor_id="rear", base_from_sensor=SE2(-rear_overhang_m, 0.0, math.pi), period_ticks=7),
        RadarSpec(
            sensor_id="corner_left", base_from_sensor=SE2(front_m, 0.8, math.radians(60)), period_ticks=6
        ),
        RadarSpec(
            sensor_id="corner_right", base_from_sensor=SE2(front_m, -0.8, math.radians(-60)), period_ticks=8
        ),
    )


@dataclass(slots=True)
class Recording:
    """Radar messages (map frame, capture-stamped) and ground truth on the evaluation grid."""

    messages: list[DetectedBoxes]
    truth: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # stamp -> ids, (N, 2) xy
    ego_xy_m: tuple[float, float] = (0.0, 0.0)
    seconds: float = 0.0


def radar_class(rcs_dbsm: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
    """A per-detection class guess from RCS and speed (the track's HMM smooths it)."""
    cls = np.where(rcs_dbsm >= 3.0, int(ObjectClass.CAR), int(ObjectClass.PEDESTRIAN))
    cls = np.where((cls == int(ObjectClass.PEDESTRIAN)) & (speed_mps > 3.0), int(ObjectClass.CYCLIST), cls)
    return np.where(rcs_dbsm < -11.0, int(ObjectClass.ANIMAL), cls).astype(np.int64)


def radar_message(frame: RadarFrame, map_from_sensor: SE2) -> DetectedBoxes:
    """A radar frame as map-frame boxes with their Doppler over-ground velocity."""
    obj = frame.objects
    n = obj.shape[0]
    c, s = math.cos(map_from_sensor.yaw_rad), math.sin(map_from_sensor.yaw_rad)
    x = map_from_sensor.x_m + c * obj[:, 0] - s * obj[:, 1]
    y = map_from_sensor.y_m + s * obj[:, 0] + c * obj[:, 1]
    vx = c * obj[:, 2] - s * obj[:, 3]
    vy = s * obj[:, 2] + c * obj[:, 3]
    speed = np.hypot(vx, vy)
    cls = radar_class(obj[:, 4], speed)
    size = np.array([RADAR_BOX_SIZE[ObjectClass(int(k))] for k in cls]).reshape(n, 3)
    # A radar reports the reflection point on the object's near face: the box centre lies half the
    # footprint's smaller side further along the line of sight. Without this shift, radars looking at
    # one car from different places report points metres apart, which start duplicate tracks.
    rng_m = np.maximum(np.hypot(obj[:, 0], obj[:, 1]), 1e-6)
    behind = 0.5 * np.minimum(size[:, 0], size[:, 1]) / rng_m
    x = x + behind * (x - map_from_sensor.x_m)
    y = y + behind * (y - map_from_sensor.y_m)
    # Heading from the velocity where it is measurable; standing objects keep the sensor's bearing.
    yaw = np.where(speed > 0.5, np.arctan2(vy, vx), map_from_sensor.yaw_rad)
    boxes = np.column_stack([x, y, 0.5 * size[:, 2], size, yaw])
    return DetectedBoxes(
        stamp=frame.stamp,
        frame="map",
        source=frame.sensor_id,
        boxes=boxes,
        class_id=cls,
        score=np.clip(0.5 + 0.02 * obj[:, 4], 0.05, 1.0),
        velocity_mps=np.column_stack([vx, vy]),
        has_velocity=np.ones(n, bool),
        attributes=np.zeros((n, 0)),
    )


def base_from_lidar(spec: LidarSpec) -> np.ndarray:
    """(4, 4) mounting of a simulated LiDAR (the extrinsics a real vehicle's calibration gives)."""
    c, s = math.cos(spec.yaw_rad), math.sin(spec.yaw_rad)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = (spec.x_m, spec.y_m, spec.z_m)
    return m


def lidar_message(result: LidarPipelineResult, map_from_base: SE2) -> DetectedBoxes:
    """LiDAR clusters as map-frame boxes, class UNKNOWN (no camera here), no velocity."""
    cl = result.clusters
    n = len(cl.table)
    c, s = math.cos(map_from_base.yaw_rad), math.sin(map_from_base.yaw_rad)
    bx, by = cl.col("x_m"), cl.col("y_m")
    z0, z1 = cl.col("z_min_m"), cl.col("z_max_m")
    boxes = np.column_stack(
        [
            map_from_base.x_m + c * bx - s * by,
            map_from_base.y_m + s * bx + c * by,
            0.5 * (z0 + z1),
            np.maximum(cl.col("length_m"), 0.1),
            np.maximum(cl.col("width_m"), 0.1),
            np.maximum(z1 - z0, 0.1),
            cl.col("yaw_rad") + map_from_base.yaw_rad,
        ]
    ).reshape(n, 7)
    return DetectedBoxes(
        stamp=result.cloud.stamp,
        frame="map",
        source="lidar",
        boxes=boxes,
        class_id=np.full(n, int(ObjectClass.UNKNOWN), np.int64),
        score=np.clip(cl.col("confidence"), 0.05, 1.0),
        velocity_mps=np.zeros((n, 2)),
        has_velocity=np.zeros(n, bool),
        attributes=np.zeros((n, 0)),
    )


def record(seed: int, seconds: float, weather: str, *, lidar: bool = False) -> Recording:
    """Run the simulator (the shuttle standing) and keep every radar frame and the ground truth.

    With ``lidar``, the three simulated LiDARs (:class:`RawSensorRig`) are run through
    :class:`LidarPipeline` every rig frame and their clusters added as a fifth source, ``lidar``.
    """
    hdmap = load_campus_map()
    service = route_polyline(hdmap, campus_shuttle_loop(hdmap), closed=True)
    geometry = VehicleGeometry()
    sim = Simulation(scene(seed, seconds, weather), hdmap, service, geometry, TICK_US)
    sim.sensors = SensorSuite(
        sim.world, seed, TICK_US, radars=radar_rig(geometry.front_from_rear_axle_m, geometry.rear_overhang_m)
    )
    mounts = {r.sensor_id: r.base_from_sensor for r in sim.sensors.radars}
    rig = RawSensorRig(sim.world, seed, TICK_US) if lidar else None
    pipeline = LidarPipeline()
    extrinsics = {spec.sensor_id: base_from_lidar(spec) for spec in rig.lidar_specs} if rig else {}
    out = Recording(messages=[], seconds=seconds)
    for tick in parked_ticks(sim, range(int(seconds * 1e6 / TICK_US) + 1)):  # no stack: the brake holds
        sim.sensors.sample(tick)
        e = sim.world.ego.state
        map_from_base = SE2(e.x_m, e.y_m, e.yaw_rad)
        if rig is not None:
            sweeps = [f for f, _ in rig.sample(tick) if isinstance(f, LidarSweep)]
            if sweeps:  # the shuttle stands still: no de-skew trajectory needed
                out.messages.append(lidar_message(pipeline.process(sweeps, extrinsics), map_from_base))
        for frame in sim.sensors.deliver(10**15):  # all captured frames; delivery is modelled below
            if isinstance(frame, RadarFrame):
                out.messages.append(radar_message(frame, map_from_base.compose(mounts[frame.sensor_id])))
        now = tick * TICK_US
        if now % EVAL_PERIOD_US == 0:
            agents = [
                a
                for a in sim.world.agents
                if a.active and math.hypot(a.x_m - e.x_m, a.y_m - e.y_m) <= SCENE_RANGE_M
            ]
            out.truth[now] = (
                np.array([a.id for a in agents], np.int64),
                np.array([(a.x_m, a.y_m) for a in agents], np.float64).reshape(-1, 2),
            )
    out.ego_xy_m = (sim.world.ego.state.x_m, sim.world.ego.state.y_m)
    return out


def deliveries(rec: Recording, order: str, seed: int) -> list[tuple[int, DetectedBoxes]]:
    """(delivery time, message) in delivery order.

    Every frame gets a latency drawn uniformly in ``[0, MAX_LATENCY_US]`` (the same draws in both modes).
    ``shuffled``: each frame is handed over when it arrives, so frames come out of capture order.
    ``ordered``: frames are handed over in capture order, each as soon as it and every earlier-stamped
    frame have arrived (what a reorder buffer in front of a tracker without rollback does).
    """
    rng = component_rng(seed, "tracking_sim.delivery")
    lat = rng.integers(0, MAX_LATENCY_US + 1, len(rec.messages))
    items = sorted(
        ((int(m.stamp), m.source, int(d), m) for m, d in zip(rec.messages, lat, strict=True)),
        key=lambda item: item[:2],
    )
    if order == "ordered":
        arrival = np.maximum.accumulate(np.array([st + d for st, _, d, _ in items], np.int64))
        return [(int(t), m) for t, (_, _, _, m) in zip(arrival, items, strict=True)]
    if order == "shuffled":
        due = sorted(((st + d, st, src, m) for st, src, d, m in items), key=lambda item: item[:3])
        return [(t, m) for t, _, _, m in due]
    raise ValueError(f"order: expected 'ordered' or 'shuffled', got {order!r}")


@dataclass(slots=True)
class FeedResult:
    """Published tracks on the evaluation grid and how many messages were fed, dropped, rolled back.

    ``final`` is the tracker's output at the end of the recording once every frame has been delivered
    (frames arriving after the last evaluation instant included): rollback makes it independent of the
    arrival order. ``inherited``: published ids handed over across replays (see ``published_ids``).
    """

    published: dict[int, tuple[np.ndarray, np.ndarray]]  # query stamp -> track ids, (M, 2) xy
    fed: int
    dropped: int
    rollbacks: int
    seconds: float
    final: TrackedBoxes | None = None
    inherited: int = 0


class FeedObserver(Protocol):
    """Looks inside a fed tracker (benchmark instrumentation, e.g. ``sim_id_switches.IdObserver``)."""

    def attach(self, tracker: AutoTrack) -> None: ...

    def published(self, now_us: int, tracker: AutoTrack) -> None: ...


def feed(
    rec: Recording,
    delivered: list[tuple[int, DetectedBoxes]],
    *,
    rollback: bool,
    config: AutoTrackConfig | None = None,
    observer: FeedObserver | None = None,
) -> FeedResult:
    """Feed the tracker in delivery order; every 100 ms, score what it publishes for ``now``.

    ``rollback=False`` is the baseline a tracker without a message queue has: a message older than the
    newest one processed is dropped. ``observer`` is told of the tracker and of every scored instant.
    """
    import time

    tracker = AutoTrack(config)
    if observer is not None:
        observer.attach(tracker)
    newest = -1
    fed = dropped = 0
    k = 0
    published: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    t0 = time.process_time()
    end = int(rec.seconds * 1e6)
    for now in range(0, end + 1, EVAL_PERIOD_US):
        while k < len(delivered) and delivered[k][0] <= now:
            msg = delivered[k][1]
            k += 1
            if not rollback and int(msg.stamp) < newest:
                dropped += 1
                continue
            tracker.update(msg)
            newest = max(newest, int(msg.stamp))
            fed += 1
        if now in rec.truth:
            tr = tracker.tracks(Stamp(now))
            published[now] = (tr.ids.copy(), tr.table[:, 0:2].copy())
            if observer is not None:
                observer.published(now, tracker)
    seconds = time.process_time() - t0
    for _, msg in delivered[k:]:  # the frames still in flight at the end
        if rollback or int(msg.stamp) >= newest:
            tracker.update(msg)
            newest = max(newest, int(msg.stamp))
    return FeedResult(
        published=published,
        fed=fed,
        dropped=dropped,
        rollbacks=tracker.rollbacks,
        seconds=seconds,
        final=tracker.tracks(Stamp(end)),
        inherited=tracker.published_ids.inherited,
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class Score:
    """CLEAR-MOT-style counts of published tracks against ground truth within ``SCENE_RANGE_M``."""

    id_switches: int
    matches: int
    misses: int
    false_tracks: int
    rmse_m: float
    median_m: float
    p95_m: float

    def as_dict(self) -> dict[str, float]:
        return {f: getattr(self, f) for f in self.__slots__}  # type: ignore[attr-defined]


def matched(rec: Recording, result: FeedResult) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Per scored instant: (stamp, truth rows, track rows) matched (Hungarian on distance, 3 m gate)."""
    for stamp, (tids, txy) in sorted(result.published.items()):
        gids, gxy = rec.truth[stamp]
        if gids.size and tids.size:
            d = np.linalg.norm(gxy[:, None, :] - txy[None, :, :], axis=2)
            gi, ti = linear_sum_assignment(np.where(d <= MATCH_GATE_M, d, 1e6))
            ok = d[gi, ti] <= MATCH_GATE_M
            gi, ti = gi[ok], ti[ok]
        else:
            gi = ti = np.zeros(0, np.int64)
        yield stamp, gi, ti


def score(rec: Recording, result: FeedResult) -> Score:
    """Match tracks to objects each query (Hungarian on distance, 3 m gate); count ID switches."""
    last: dict[int, int] = {}
    switches = matches = misses = false_tracks = 0
    errors: list[np.ndarray] = []
    for stamp, gi, ti in matched(rec, result):
        tids, txy = result.published[stamp]
        gids, gxy = rec.truth[stamp]
        for g, t in zip(gi, ti, strict=True):
            gid, tid = int(gids[g]), int(tids[t])
            if gid in last and last[gid] != tid:
                switches += 1
            last[gid] = tid
        matches += gi.size
        misses += gids.size - gi.size
        # Tracks beyond the scored range are of objects the truth does not list: not false.
        unmatched = np.ones(tids.size, bool)
        unmatched[ti] = False
        near = (
            np.hypot(txy[:, 0] - rec.ego_xy_m[0], txy[:, 1] - rec.ego_xy_m[1]) <= SCENE_RANGE_M - MATCH_GATE_M
        )
        false_tracks += int(np.count_nonzero(unmatched & near))
        errors.append(np.linalg.norm(gxy[gi] - txy[ti], axis=1))
    err = np.concatenate(errors) if errors else np.zeros(0)
    return Score(
        id_switches=switches,
        matches=int(matches),
        misses=int(misses),
        false_tracks=int(false_tracks),
        rmse_m=float(np.sqrt(np.mean(err**2))) if err.size else math.nan,
        median_m=float(np.median(err)) if err.size else math.nan,
        p95_m=float(np.percentile(err, 95)) if err.size else math.nan,
    )
