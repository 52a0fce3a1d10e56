"""Camera detector model: projection, field of view, occlusion, truncation, degradation, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.camera_model import CameraDetector, PinholeCamera
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim.camera import CameraDetectorConfig, CameraDetectorModel, CameraScene, default_cameras
from lastmile.sim.weather import Weather

FRONT, REAR = default_cameras(VehicleGeometry())
EXACT = CameraDetectorConfig(
    detect_prob={c: 1.0 for c in ObjectClass},
    confusion_prob=0.0,
    false_positives_per_frame=0.0,
    pixel_noise_px=0.0,
    pixel_noise_rel=0.0,
)


def scene(*rows: tuple[float, ...]) -> CameraScene:
    """Rows: x, y, yaw, length, width, height, class, id (map frame); the shuttle at the origin."""
    return CameraScene(map_from_base=SE2(0.0, 0.0, 0.0), boxes=np.array(rows, dtype=float).reshape(-1, 8))


def car(x: float, y: float, oid: int = 1, height: float = 1.5) -> tuple[float, ...]:
    return (x, y, 0.0, 4.5, 1.8, height, float(ObjectClass.CAR), float(oid))


def pedestrian(x: float, y: float, oid: int = 2) -> tuple[float, ...]:
    return (x, y, 0.0, 0.5, 0.5, 1.75, float(ObjectClass.PEDESTRIAN), float(oid))


def exact(camera: PinholeCamera = FRONT) -> CameraDetectorModel:
    return CameraDetectorModel(camera, Weather.CLEAR, 1.0, 0, EXACT)


def test_principal_axis_projects_to_the_principal_point() -> None:
    cam = PinholeCamera.from_fov("c", 2048, 1536, 70.0, 1.0, 0.0, 2.0)
    p = cam.to_camera(np.array([[11.0, 0.0, 2.0], [11.0, 1.0, 2.0]]))
    uv = cam.pixels_from_camera(p)
    assert uv[0] == pytest.approx([1024.0, 768.0])
    assert uv[1, 0] < 1024.0  # a point to the left (base +y) is left in the image
    assert np.allclose(cam.K @ np.array([0.0, 0.0, 1.0]), [1024.0, 768.0, 1.0])


def test_object_in_view_is_boxed_around_its_projection() -> None:
    dets, ids = exact().detect_with_truth(scene(car(20.0, 1.0)), Stamp(0))
    assert ids.tolist() == [1]
    x, y = 20.0, 1.0
    corners = np.array(
        [[x + sx * 2.25, y + sy * 0.9, z] for sx in (-1, 1) for sy in (-1, 1) for z in (0.0, 1.5)]
    )
    uv = FRONT.pixels_from_camera(FRONT.to_camera(corners))
    expected = [*uv.min(axis=0), *uv.max(axis=0)]
    assert dets.boxes[0, :4] == pytest.approx(expected, abs=1e-3)
    assert dets.boxes[0, 4] == ObjectClass.CAR
    assert 0.0 < dets.boxes[0, 5] <= 1.0


def test_behind_the_camera_or_outside_its_field_is_not_seen() -> None:
    behind = scene(car(-12.0, 0.0))
    assert len(exact().detect(behind, Stamp(0)).boxes) == 0
    assert len(exact(REAR).detect(behind, Stamp(0)).boxes) == 1  # the rear camera sees it
    beside = scene(car(3.0, 20.0))  # 80 deg off the axis of a 70 deg camera
    assert len(exact().detect(beside, Stamp(0)).boxes) == 0


def test_occluded_object_is_not_detected() -> None:
    alone = exact().detect_with_truth(scene(pedestrian(30.0, 0.0)), Stamp(0))[1]
    assert alone.tolist() == [2]
    van = car(18.0, 0.0, oid=1, height=2.6)
    hidden = exact().detect_with_truth(scene(van, pedestrian(30.0, 0.0)), Stamp(0))[1]
    assert hidden.tolist() == [1]


def test_truncated_box_is_clipped_at_the_border_and_dropped_when_mostly_out() -> None:
    # A car whose left half sticks out of the image's left border (30 deg left of a 35 deg half-FOV).
    half_in = scene(car(FRONT.x_m + 12.0, 12.0 * math.tan(math.radians(33.0))))
    dets = exact().detect(half_in, Stamp(0))
    assert len(dets.boxes) == 1
    assert dets.boxes[0, 0] == 0.0
    mostly_out = scene(car(FRONT.x_m + 12.0, 12.0 * math.tan(math.radians(41.0))))
    assert len(exact().detect(mostly_out, Stamp(0)).boxes) == 0


def test_far_and_small_objects_are_not_detected() -> None:
    goose = (70.0, 0.0, 0.0, 0.5, 0.3, 0.4, float(ObjectClass.ANIMAL), 5.0)  # ~8 px tall at 70 m
    assert len(exact().detect(scene(goose), Stamp(0)).boxes) == 0
    assert len(exact().detect(scene(car(95.0, 0.0)), Stamp(0)).boxes) == 0  # beyond 80 m


def test_snow_and_darkness_cost_detections_and_add_false_boxes() -> None:
    far_pedestrians = scene(*(pedestrian(40.0, y, oid=i) for i, y in enumerate((-6.0, -3.0, 0.0, 3.0, 6.0))))

    def rates(weather: Weather, daylight: float) -> tuple[float, float]:
        model = CameraDetectorModel(FRONT, weather, daylight, seed=3)
        found = false = 0
        for k in range(200):
            ids = model.detect_with_truth(far_pedestrians, Stamp(k))[1]
            found += int((ids >= 0).sum())
            false += int((ids < 0).sum())
        return found / (200 * 5), false / 200

    day, day_fp = rates(Weather.CLEAR, 1.0)
    snow_night, snow_night_fp = rates(Weather.SNOW, 0.0)
    assert day > 0.85
    assert snow_night < day - 0.2
    assert snow_night_fp > day_fp


def test_same_seed_same_detections() -> None:
    s = scene(car(20.0, 1.0), pedestrian(15.0, -3.0, 2))
    runs = [
        CameraDetectorModel(FRONT, Weather.SNOW, 0.5, seed).detect(s, Stamp(0)).boxes.tobytes()
        for seed in (1, 1)
    ]
    assert runs[0] == runs[1]


def test_detector_satisfies_the_protocol_a_real_network_would_implement() -> None:
    detector: CameraDetector = exact()
    out = detector.detect(scene(car(20.0, 0.0)), Stamp(7))
    assert out.camera_id == "front" and out.stamp == Stamp(7)


def test_bad_camera_configs_raise_clear_errors() -> None:
    with pytest.raises(ConfigError, match="x_m"):
        PinholeCamera.from_fov("c", 640, 480, 60.0, float("nan"), 0.0, 1.0)
    with pytest.raises(ConfigError, match="hfov_deg"):
        PinholeCamera.from_fov("c", 640, 480, 200.0, 0.0, 0.0, 1.0)
    with pytest.raises(ConfigError, match="daylight"):
        CameraDetectorModel(FRONT, Weather.CLEAR, 2.0, 0)
    with pytest.raises(ConfigError, match="Weather"):
        CameraDetectorModel(FRONT, "hail", 1.0, 0)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="false_positives_per_frame"):
        CameraDetectorConfig(false_positives_per_frame=-1.0)
    with pytest.raises(ConfigError, match="CameraScene"):
        exact().detect("an image", Stamp(0))  # type: ignore[arg-type]
