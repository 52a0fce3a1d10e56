"""Raw-sensor perception in the stack: what reaches decision making, and what is kept from it."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from lastmile.core.boxes3d import DetectedBoxes
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import DetectedObjects
from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.hdmap.drivable import DrivableRaster
from lastmile.perception.snow_surface import curb_distance_m
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.sim.scenario import Scenario, StaticObstacle
from lastmile.stack.raw_perception import RawPerception, RawPerceptionConfig
from lastmile.stack.shuttle_stack import ShuttleStack, StackConfig

_CURB_LINE_FRAMES: list[int] = []
_LAST_CURB_LINES: list[object] = []
_DETECTIONS: list[DetectedObjects] = []


@functools.cache
def _obstacle_run() -> tuple[list[tuple[float, float, int, float]], float, float, RawPerception]:
    """The shuttle drives at a 0.8 m box on its lane 60 m ahead, perceiving through LiDAR only."""
    scenario = Scenario(name="box_ahead", minutes=0.5, static_obstacles=(StaticObstacle(route_s_m=60.0),))
    loop = build_closed_loop(scenario)
    stack = loop.software
    assert isinstance(stack, ShuttleStack)
    assert stack.raw is not None
    pipeline = stack.raw.pipeline
    process = pipeline.process

    def counting(*args: object) -> object:
        # How many frames the stack gave the pipeline the map's curb lines with.
        lines = args[5] if len(args) > 5 else None
        _CURB_LINE_FRAMES.append(len(lines) if lines is not None else 0)  # type: ignore[arg-type]
        _LAST_CURB_LINES[:] = [lines]
        return process(*args)

    pipeline.process = counting  # type: ignore[method-assign]
    box = loop.world.road_users[-1]
    trace = []
    for record in loop.ticks(round(30e6 / loop.tick_us)):
        tick = record.tick
        assert record.output is not None
        _DETECTIONS.extend(record.output.detections or ())
        if tick % 10 == 0 and stack._route_s is not None:
            near = [float(np.hypot(r[0] - box.x_m, r[1] - box.y_m)) for r in stack._tracks.table.tolist()]
            trace.append((tick / 100.0, stack._route_s, len(near), min(near, default=np.inf)))
    assert stack.raw is not None
    return trace, box.x_m, box.y_m, stack.raw


def test_the_stack_stops_for_a_box_it_only_sees_in_its_lidar_clusters() -> None:
    trace, _, _, raw = _obstacle_run()
    # The box is tracked (within 0.5 m of where it stands) long before the shuttle reaches it...
    seen = [t for t, s, _, d in trace if d < 0.5]
    assert seen and seen[0] < 8.0, trace[:40]
    # ...and the shuttle stops short of it and stays there (route s of the rear axle; box at 60 m).
    final_s = trace[-1][1]
    assert 45.0 < final_s < 60.0 - 4.0, trace[-5:]
    assert raw.stats.rig_frames >= 290 and raw.stats.incomplete_frames == 0
    assert raw.stats.skipped_no_pose <= 1  # the first frame may precede the first fix


def test_the_stack_outputs_the_fused_detections_its_tracker_consumed() -> None:
    _, box_x, box_y, raw = _obstacle_run()
    # One message per processed rig frame, each the late fusion's output in the map frame (a frame
    # processed after the last planning cycle waits for the next one).
    assert len(_DETECTIONS) + len(raw.drain_detections()) == raw.stats.rig_frames
    assert {(d.source, d.frame) for d in _DETECTIONS} == {("fusion", "map")}
    dist = [np.hypot(d.table[:, 0] - box_x, d.table[:, 1] - box_y).min() for d in _DETECTIONS if len(d)]
    assert sum(x < 0.5 for x in dist) > raw.stats.rig_frames // 2


def test_the_stack_gives_the_pipeline_the_map_curb_lines_and_curb_faces_are_not_objects() -> None:
    *_, raw = _obstacle_run()
    # Driving along a curbed road, every frame came with the curb lines near the shuttle.
    assert len(_CURB_LINE_FRAMES) == raw.stats.rig_frames and min(_CURB_LINE_FRAMES) > 0
    res = raw.last_result
    assert res is not None
    # The curb lines the stack passes run where the map's curbs are, in the cloud's base frame.
    curb = np.asarray(raw.layers.hdmap.curbs[0].xy_m, dtype=float)
    mid = curb[len(curb) // 2]
    pose = SE2(float(mid[0]), float(mid[1]), 0.3)
    lines = raw.curbs.lines_near(pose, 10.0)
    assert lines and float(curb_distance_m(lines, np.zeros((1, 2)), 0.05)[0]) < 0.05
    assert all(float(np.hypot(*line.T).min()) <= 10.0 + 2.0 for line in lines)  # one vertex beyond
    assert raw.curbs.lines_near(SE2(1e4, 1e4, 0.0), 45.0) == []
    # No object left is a curb face: low and on a curb line (near the shuttle the ground stage
    # already takes the face, as the sidewalk's edge; farther on, the curb-side stage drops it).
    last_lines = _LAST_CURB_LINES[0]  # the last frame's, in its base frame as the clusters
    assert isinstance(last_lines, list) and last_lines
    xy = res.clusters.table[:, 0:2]
    low = res.clusters.col("z_max_m") <= 0.3
    assert len(xy) and not (low & (curb_distance_m(last_lines, xy, 0.05) < 0.5)).any()


def _perception() -> RawPerception:
    stack = build_closed_loop(Scenario(name="unit", minutes=0.1)).software
    assert isinstance(stack, ShuttleStack) and stack.raw is not None
    return RawPerception(
        RawPerceptionConfig(),
        stack.layers,
        stack.config.lidar_mounts,
        stack.config.cameras,
        stack.config.radar_mounts,
    )


def _off_and_on_road(raw: RawPerception) -> tuple[np.ndarray, np.ndarray]:
    route = raw.layers.centerline
    for s in np.arange(0.0, route.length_m, 5.0):
        x, y, h = route.point_at(float(s))
        off = np.array([x - 15.0 * np.sin(h), y + 15.0 * np.cos(h)])
        if raw.road.raster.classify(off[None, :])[0] == DrivableRaster.OUTSIDE:
            return off, np.array([x, y])
    raise AssertionError("no off-road point 15 m beside the route")


def test_scenery_off_the_road_is_hidden_but_road_users_and_anything_on_the_road_are_not() -> None:
    raw = _perception()
    off, on = _off_and_on_road(raw)
    # Four objects seen for 1.5 s: a static unclassified one off the road (a pole), the same on the
    # road, a pedestrian the camera named standing off the road, and an unclassified one walking there.
    for k in range(16):
        t_s = 0.1 * k
        xy = np.array([off, on, off + np.array([3.0, 0.0]), off + np.array([-3.0 + 1.2 * t_s, 0.0])])
        raw.tracker.update(
            DetectedBoxes(
                stamp=Stamp(round(t_s * 1e6)),
                frame="map",
                source="lidar_fusion",
                boxes=np.column_stack([xy, np.full((4, 1), 0.8), np.full((4, 3), 0.6), np.zeros((4, 1))]),
                class_id=np.array([0, 0, int(ObjectClass.PEDESTRIAN), 0]),
                score=np.full(4, 0.6),
                velocity_mps=np.zeros((4, 2)),
                has_velocity=np.zeros(4, bool),
                attributes=np.zeros((4, 0)),
            )
        )
    tracks = raw.tracks(Stamp(1_500_000))
    kept = {(round(r[0] - off[0]), round(r[1] - off[1])) for r in tracks.table.tolist()}
    assert len(raw.tracker.tracks(Stamp(1_500_000))) == 4
    assert len(tracks) == 3 and (0, 0) not in kept
    assert raw.stats.scenery_tracks_hidden == 1


def test_bad_calibration_and_unknown_sensors_are_refused() -> None:
    raw = _perception()
    with pytest.raises(MessageError, match="calibrated LiDAR"):
        raw.on_frame(LidarSweep(stamp=Stamp(0), sensor_id="roof", points=np.zeros((1, 6))), Stamp(0))
    with pytest.raises(ConfigError, match="lidar_mounts"):
        StackConfig(perception_mode=PerceptionMode.LIDAR_CAMERA_RADAR)
    with pytest.raises(ConfigError, match="perception_mode"):
        StackConfig(perception_mode="oracle")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"\(4, 4\)"):
        RawPerception(RawPerceptionConfig(), raw.layers, {"front": np.eye(3)}, (), {})
    with pytest.raises(ConfigError, match="set_timeout_us"):
        RawPerceptionConfig(set_timeout_us=0)
