"""The ONNX detector plug-ins: contracts checked at load, detections through late fusion into tracks."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from onnx import TensorProto

from lastmile.core.boxes3d import DetectedBoxes
from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.object_class import ObjectClass
from lastmile.core.stamp import Stamp
from lastmile.perception.bev_raster import BevChannel, BevGrid, bev_tensor
from lastmile.perception.camera_detector import CameraDetectorConfig, OnnxCameraDetector
from lastmile.perception.cluster_geometry import describe_clusters
from lastmile.perception.late_fusion import fuse_objects
from lastmile.perception.lidar_detector import (
    DetectorMerge,
    LidarDetections,
    LidarDetectorConfig,
    OnnxLidarDetector,
    circle_nms,
    merge_with_clusters,
)
from lastmile.tracking.autotrack import AutoTrack, AutoTrackConfig
from tests.perception.tiny_onnx import bev_peak_detector, red_blob_detector

GRID = BevGrid(
    x_min_m=-10.0,
    x_max_m=30.0,
    y_min_m=-10.0,
    y_max_m=10.0,
    z_min_m=0.0,
    z_max_m=3.0,
    cell_m=0.5,
    channels=(BevChannel.MAX_HEIGHT, BevChannel.DENSITY),
)


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A flat road with a 1.7 m person-sized column at (5.0, 2.0) and a 1.0 m post at (15.0, -4.0)."""
    person = rng.uniform([4.8, 1.8, 0.0], [5.2, 2.2, 1.7], (300, 3))
    post = rng.uniform([14.9, -4.1, 0.0], [15.1, -3.9, 1.0], (60, 3))
    road = rng.uniform([-10.0, -10.0, 0.0], [30.0, 10.0, 0.05], (4000, 3))
    xyz = np.vstack([person, post, road])
    return xyz, np.full(len(xyz), 80.0)


def _lidar_model(tmp_path: Path, **kw: object) -> Path:
    args: dict[str, object] = {"threshold": 0.5, "class_id": int(ObjectClass.PEDESTRIAN)}
    args["box_lwh_m"] = (0.6, 0.6, 1.7)
    args.update(kw)
    return bev_peak_detector(tmp_path / "bev.onnx", GRID, **args)  # type: ignore[arg-type]


def test_the_bev_raster_puts_each_point_in_its_documented_cell_and_channel() -> None:
    xyz = np.array([[0.1, 0.1, 1.2], [0.4, 0.2, 0.3], [-9.9, 9.9, 2.0], [31.0, 0.0, 1.0], [0.0, 0.0, 3.5]])
    t = bev_tensor(xyz, np.array([51.0, 255.0, 0.0, 9.0, 9.0]), BevGrid(**{**_grid_kw(), "channels": _all()}))
    assert t.shape == (1, 4, 80, 40) and t.dtype == np.float32
    occ, dens, top, inten = t[0]
    # Row along x from x_min, column along y from y_min: (0.1, 0.1) and (0.4, 0.2) share cell (20, 20).
    assert occ.sum() == 2 and occ[20, 20] == 1 and occ[0, 39] == 1  # the out-of-box points are left out
    assert dens[20, 20] == pytest.approx(np.log(3) / np.log(64))
    assert top[20, 20] == pytest.approx(1.2) and inten[20, 20] == pytest.approx(1.0)
    with pytest.raises(MessageError, match=r"expected \(N, 3\) points"):
        bev_tensor(np.zeros((3, 2)), np.zeros(3), GRID)
    with pytest.raises(ConfigError, match=r"whole number of 0\.3 m cells"):
        BevGrid(x_min_m=0.0, x_max_m=10.0, cell_m=0.3)


def _grid_kw() -> dict[str, object]:
    return {
        "x_min_m": -10.0,
        "x_max_m": 30.0,
        "y_min_m": -10.0,
        "y_max_m": 10.0,
        "z_min_m": 0.0,
        "cell_m": 0.5,
    }


def _all() -> tuple[BevChannel, ...]:
    return (BevChannel.OCCUPANCY, BevChannel.DENSITY, BevChannel.MAX_HEIGHT, BevChannel.MAX_INTENSITY)


def test_the_lidar_detector_finds_the_objects_its_model_is_built_to_find_and_repeats_bit_for_bit(
    tmp_path: Path,
) -> None:
    det = OnnxLidarDetector(LidarDetectorConfig(model=str(_lidar_model(tmp_path)), grid=GRID))
    xyz, inten = _scene(np.random.default_rng(0))
    a = det.detect(xyz, inten)
    b = det.detect(xyz, inten)
    assert np.array_equal(a.boxes, b.boxes) and np.array_equal(a.scores, b.scores)
    # One box per object (the road is under the 0.5 m threshold), at its cell, as the model states.
    order = np.argsort(a.boxes[:, 0])
    assert len(a) == 2
    np.testing.assert_allclose(a.boxes[order, :2], [[5.0, 2.0], [15.0, -4.0]], atol=0.5)
    assert (a.class_id == int(ObjectClass.PEDESTRIAN)).all()
    np.testing.assert_allclose(a.boxes[0, 3:6], [0.6, 0.6, 1.7], rtol=1e-6)
    # The score is the model's (max height capped at 1); min_score drops what is below it.
    high = OnnxLidarDetector(LidarDetectorConfig(model=det.config.model, grid=GRID, min_score=1.0))
    assert len(high.detect(xyz, inten)) == 1


def test_a_model_that_breaks_the_contract_is_refused_at_load_in_one_line(tmp_path: Path) -> None:
    def load(path: Path, grid: BevGrid = GRID) -> None:
        OnnxLidarDetector(LidarDetectorConfig(model=str(path), grid=grid))

    renamed = bev_peak_detector(
        tmp_path / "renamed.onnx", GRID, threshold=0.5, class_id=2, box_lwh_m=(1, 1, 1), bev_name="points"
    )
    with pytest.raises(ConfigError) as err:
        load(renamed)
    msg = str(err.value)
    assert "\n" not in msg and "expected input 'bev' float32 (1, 2, 80, 40)" in msg and "'points'" in msg
    # A model built for another grid: one channel fewer.
    one_channel = BevGrid(**{**_grid_kw(), "channels": (BevChannel.MAX_HEIGHT,)})
    with pytest.raises(ConfigError, match=r"expected input 'bev' float32 \(1, 1, 80, 40\), got 'bev' tensor"):
        load(_lidar_model(tmp_path), one_channel)
    doubles = _lidar_model(tmp_path, scores_dtype=TensorProto.DOUBLE)
    with pytest.raises(
        ConfigError, match=r"expected output 'scores' float32 \(1, \?\), got 'scores' tensor\(double\)"
    ):
        load(doubles)
    with pytest.raises(ConfigError, match="expected an ONNX model file, got no such file"):
        load(tmp_path / "absent.onnx")
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"not a model")
    with pytest.raises(ConfigError, match="expected a valid ONNX model, got one ONNX Runtime cannot load"):
        load(garbage)


def test_without_onnxruntime_a_configured_detector_says_what_to_install(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    with pytest.raises(ConfigError, match=r"pip install 'lastmile\[detector\]'"):
        OnnxLidarDetector(LidarDetectorConfig(model=str(_lidar_model(tmp_path)), grid=GRID))


def test_circle_nms_keeps_one_car_per_four_metres_but_two_pedestrians_a_metre_apart() -> None:
    xy = np.array([[0.0, 0.0], [2.0, 0.0], [10.0, 0.0], [11.0, 0.0]])
    cls = np.array([1, 1, 2, 2])
    kept = circle_nms(xy, np.array([0.5, 0.9, 0.8, 0.7]), cls)
    assert kept.tolist() == [1, 2, 3]


def test_detections_replace_the_clusters_they_cover_and_the_rest_stay_unclassified() -> None:
    rng = np.random.default_rng(1)
    xyz, inten = _scene(rng)
    objects = xyz[:360]
    labels = np.r_[np.zeros(300, np.int64), np.ones(60, np.int64)]
    clusters = describe_clusters(objects, inten[:360], labels)
    assert len(clusters) == 2
    det = LidarDetections(
        boxes=np.array([[5.1, 2.1, 0.85, 0.6, 0.6, 1.7, 0.0]]),
        scores=np.array([0.8]),
        class_id=np.array([int(ObjectClass.PEDESTRIAN)]),
    )
    merged = merge_with_clusters(clusters, det, DetectorMerge.WITH_CLUSTERS)
    assert merged.replaced_clusters == 1 and len(merged.clusters) == 2
    assert merged.class_id.tolist() == [int(ObjectClass.UNKNOWN), int(ObjectClass.PEDESTRIAN)]
    assert merged.clusters.table[0, 0] == pytest.approx(15.0, abs=0.2)  # the post, kept
    assert merged.from_detector.tolist() == [False, True]
    alone = merge_with_clusters(clusters, det, DetectorMerge.REPLACE_CLUSTERS)
    assert len(alone.clusters) == 1 and alone.replaced_clusters == 2
    # Late fusion keeps the detector's class and score for its row, 0.5 (LiDAR only) for the post.
    fused = fuse_objects(
        Stamp(0), merged.clusters, lidar_class_id=merged.class_id, lidar_score=merged.score
    ).objects.table
    assert fused[:, 7].tolist() == [0, int(ObjectClass.PEDESTRIAN)]
    assert fused[:, 8].tolist() == [0.5, 0.8]
    with pytest.raises(MessageError, match=r"expected lidar_class_id of shape \(2,\)"):
        fuse_objects(Stamp(0), merged.clusters, lidar_class_id=np.zeros(3, np.int64))


def _camera() -> PinholeCamera:
    return PinholeCamera.mounted(
        "front",
        fx_px=60.0,
        fy_px=60.0,
        cx_px=40.0,
        cy_px=30.0,
        width_px=80,
        height_px=60,
        x_m=1.0,
        y_m=0.0,
        z_m=1.5,
    )


def _red_where_it_projects(cam: PinholeCamera, corners: np.ndarray) -> np.ndarray:
    """An image, red over the bounding box of ``corners`` (base frame) as ``cam`` sees them."""
    uv, front = cam.pixels_from_base(corners)
    assert front.all()
    u0, v0 = np.floor(uv.min(axis=0)).astype(int)
    u1, v1 = np.ceil(uv.max(axis=0)).astype(int)
    image = np.zeros((cam.height_px, cam.width_px, 3), np.uint8)
    image[max(v0, 0) : v1, max(u0, 0) : u1, 0] = 230
    return image


def test_camera_boxes_from_an_onnx_model_name_the_lidar_object_and_the_tracker_keeps_the_class(
    tmp_path: Path,
) -> None:
    cam = _camera()
    model = red_blob_detector(tmp_path / "cam.onnx", 60, 80, threshold=0.5, class_id=int(ObjectClass.CAR))
    det = OnnxCameraDetector(CameraDetectorConfig(model=str(model)), cam)
    # A car-sized LiDAR cluster 10 m ahead; the image shows something red where it projects.
    rng = np.random.default_rng(2)
    car = rng.uniform([10.0, -0.9, 0.0], [14.0, 0.9, 1.5], (400, 3))
    clusters = describe_clusters(car, np.full(400, 80.0), np.zeros(400, np.int64))
    image = _red_where_it_projects(
        cam, np.array([[x, y, z] for x in (10.0, 14.0) for y in (-0.9, 0.9) for z in (0.0, 1.5)])
    )
    tracker = AutoTrack(AutoTrackConfig())
    for k in range(8):
        stamp = Stamp(k * 100_000)
        boxes = det.detect(image, stamp)
        assert len(boxes.boxes) == 1 and boxes.boxes[0, 4] == int(ObjectClass.CAR)
        fused = fuse_objects(stamp, clusters, cameras=[cam], camera_detections=[boxes])
        assert fused.camera_matched.all()
        o = fused.objects.table
        tracker.update(
            DetectedBoxes(
                stamp=stamp,
                frame="base",
                source="lidar_fusion",
                boxes=np.column_stack([o[:, 0:2], [0.75], o[:, 4:6], [1.5], o[:, 6]]),
                class_id=o[:, 7].astype(np.int64),
                score=o[:, 8],
                velocity_mps=o[:, 2:4],
                has_velocity=fused.radar_matched,
                attributes=np.zeros((1, 0)),
            )
        )
    tracks = tracker.tracks(Stamp(700_000))
    assert len(tracks) == 1 and int(tracks.class_id[0]) == int(ObjectClass.CAR)
    # No red, no box; an image of another size is refused in one line.
    assert len(det.detect(np.zeros((60, 80, 3), np.uint8), Stamp(0)).boxes) == 0
    with pytest.raises(
        MessageError, match=r"expected an \(H, W, 3\) = \(60, 80, 3\) RGB image, got \(48, 64, 3\)"
    ):
        det.detect(np.zeros((48, 64, 3), np.uint8), Stamp(0))
    # A model exported for another resolution is refused at load.
    with pytest.raises(ConfigError, match=r"expected input 'image' float32 \(1, 3, 60, 80\)"):
        OnnxCameraDetector(
            CameraDetectorConfig(
                model=str(red_blob_detector(tmp_path / "small.onnx", 48, 64, threshold=0.5, class_id=1))
            ),
            cam,
        )


def test_a_camera_box_without_a_class_leaves_the_lidar_detectors_class_but_a_named_one_wins(
    tmp_path: Path,
) -> None:
    cam = _camera()
    rng = np.random.default_rng(3)
    car = rng.uniform([10.0, -0.9, 0.0], [14.0, 0.9, 1.5], (400, 3))
    clusters = describe_clusters(car, np.full(400, 80.0), np.zeros(400, np.int64))
    image = _red_where_it_projects(
        cam, np.array([[x, y, z] for x in (10.0, 14.0) for y in (-0.9, 0.9) for z in (0.0, 1.5)])
    )
    prior = np.array([int(ObjectClass.CYCLIST)])
    for camera_class, expected in (
        (ObjectClass.UNKNOWN, ObjectClass.CYCLIST),
        (ObjectClass.CAR, ObjectClass.CAR),
    ):
        model = red_blob_detector(
            tmp_path / f"{camera_class}.onnx", 60, 80, threshold=0.5, class_id=int(camera_class)
        )
        boxes = OnnxCameraDetector(CameraDetectorConfig(model=str(model)), cam).detect(image, Stamp(0))
        fused = fuse_objects(
            Stamp(0),
            clusters,
            cameras=[cam],
            camera_detections=[boxes],
            lidar_class_id=prior,
            lidar_score=np.ones(1),
        )
        assert fused.camera_matched.all() and int(fused.objects.table[0, 7]) == int(expected)


def test_lastmile_perceive_with_a_detector_labels_its_boxes_with_its_class(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from lastmile.cli import app
    from tests.perception import cloud_fixtures as fx

    # The box's face 6 m ahead of a VLP-16 1.5 m up; the model calls any peak above 0.5 m a pedestrian.
    grid = BevGrid(x_min_m=0.0, x_max_m=20.0, y_min_m=-10.0, y_max_m=10.0, z_min_m=0.0, cell_m=0.5,
                   channels=(BevChannel.MAX_HEIGHT,))  # fmt: skip
    model = bev_peak_detector(
        tmp_path / "peaks.onnx",
        grid,
        threshold=0.5,
        class_id=int(ObjectClass.PEDESTRIAN),
        box_lwh_m=(1.6, 1.6, 1.6),
    )
    cloud = fx.write_kitti_bin(tmp_path / "000000.bin", fx.spinning_scan())
    config = tmp_path / "perceive.toml"
    config.write_text(
        '[sensor.model]\nname = "vlp16"\nazimuth_resolution_deg = 2.0\n'
        f"[sensor.mount]\nz_m = {fx.SENSOR_HEIGHT_M}\n"
        "[pipeline.crop]\nego_x_min_m = -0.5\nego_x_max_m = 0.5\nego_half_width_m = 0.5\n"
        '[detector]\nmodel = "replaced by --detector"\npoints = "non_ground"\n'
        "[detector.grid]\nx_min_m = 0.0\nx_max_m = 20.0\ny_min_m = -10.0\ny_max_m = 10.0\nz_min_m = 0.0\n"
        'cell_m = 0.5\nchannels = ["max_height"]\n'
    )
    out = tmp_path / "out"
    args = ["perceive", str(cloud), "--config", str(config), "--out", str(out)]
    result = CliRunner().invoke(app, [*args, "--detector", str(model)])
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in (out / "labels" / "000000.txt").read_text().splitlines()]
    near = [r for r in rows if abs(float(r[13]) - 6.25) < 0.6 and abs(float(r[11])) < 0.6]
    assert [r[0] for r in near] == ["Pedestrian"] and float(near[0][15]) == 1.0, rows
    timing = json.loads((out / "timing.json").read_text())
    assert timing[0]["stage_ms"]["detector"] > 0
    # Without --detector the file's own [detector] model is used, and it does not exist: one line.
    bad = CliRunner().invoke(app, args)
    assert bad.exit_code == 2 and "Traceback" not in bad.output
    assert bad.output.strip() == (
        "lastmile perceive: LiDAR detector model replaced by --detector: "
        "expected an ONNX model file, got no such file"
    )
