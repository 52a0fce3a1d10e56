"""Late fusion (radar first, then camera frustums in depth order) and NUS pedestrian verification."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.object_class import ObjectClass
from lastmile.core.sensor_frames import CameraDetections, RadarFrame
from lastmile.core.stamp import Stamp
from lastmile.perception.camera_geometry import box_corners_3d, box_iou
from lastmile.perception.cluster_geometry import ClusterSet, describe_clusters
from lastmile.perception.late_fusion import LateFusionConfig, fuse
from lastmile.perception.pedestrian_verification import PedestrianVerificationConfig, verify_pedestrians

CAM = PinholeCamera.mounted(
    "front",
    fx_px=800,
    fy_px=800,
    cx_px=640,
    cy_px=360,
    width_px=1280,
    height_px=720,
    x_m=4.0,
    y_m=0.0,
    z_m=1.6,
)


def _clusters(objs: list[tuple[float, float, float, float, float]]) -> ClusterSet:
    """Clusters from (x, y, length, width, height) boxes filled with points."""
    rng = np.random.default_rng(0)
    pts, labels = [], []
    for k, (x, y, length, width, h) in enumerate(objs):
        p = rng.uniform(-0.5, 0.5, (150, 3)) * [length, width, 0] + [x, y, 0]
        p[:, 2] = rng.uniform(0, h, 150)
        pts.append(p)
        labels.append(np.full(150, k))
    return describe_clusters(np.vstack(pts), np.full(150 * len(objs), 30.0), np.concatenate(labels))


def _image_box(x, y, length, width, h):
    return CAM.project_box(box_corners_3d(x, y, 0.0, h, length, width, 0.0))


def test_projection_of_a_point_on_the_optical_axis_is_the_principal_point():
    uv, front = CAM.pixels_from_base(np.array([[14.0, 0.0, 1.6], [0.0, 0.0, 1.6]]))
    assert front.tolist() == [True, False]
    assert np.allclose(uv[0], [640, 360])


def test_radar_gives_velocity_camera_gives_class_and_unmatched_is_unknown():
    cs = _clusters([(15.0, 0.0, 4.4, 1.8, 1.5), (12.0, 4.0, 0.5, 0.5, 1.7), (25.0, -6.0, 0.6, 0.3, 0.4)])
    radar = RadarFrame(
        stamp=Stamp(0), sensor_id="front", objects=np.array([[10.5, 0.2, -3.0, 0.5, 10.0, -3.0]])
    )  # radar at the bumper (x = 4.5): the car's rear at 12.8 m is 8.3 m ahead of it
    ped_box = _image_box(12.0, 4.0, 0.5, 0.5, 1.7)
    det = CameraDetections(
        stamp=Stamp(0),
        camera_id="front",
        boxes=np.array([[*ped_box, int(ObjectClass.PEDESTRIAN), 0.9]], dtype=np.float32),
    )
    out = fuse(Stamp(0), cs, [radar], {"front": SE2(4.5, 0.0, 0.0)}, [CAM], [det])
    t = out.table
    car = np.argmin(np.hypot(t[:, 0] - 15, t[:, 1]))
    ped = np.argmin(np.hypot(t[:, 0] - 12, t[:, 1] - 4))
    goose = np.argmin(np.hypot(t[:, 0] - 25, t[:, 1] + 6))
    assert t[car, 2:4].tolist() == [-3.0, 0.5] and t[car, 7] == ObjectClass.UNKNOWN
    assert t[ped, 7] == ObjectClass.PEDESTRIAN and t[ped, 2:4].tolist() == [0.0, 0.0]
    assert t[goose, 7] == ObjectClass.UNKNOWN  # no radar, no camera: kept, as an unknown object
    strict = fuse(
        Stamp(0),
        cs,
        [radar],
        {"front": SE2(4.5, 0.0, 0.0)},
        [CAM],
        [det],
        config=LateFusionConfig(confirm_with_radar=True),
    )
    assert len(strict) == 2  # the goose, confirmed by neither, is dropped in this mode


def test_the_nearer_object_claims_the_camera_box_in_depth_order():
    # A pedestrian right in front of a parked car: the camera sees one pedestrian box.
    cs = _clusters([(20.0, 0.0, 4.4, 1.8, 1.5), (12.0, 0.0, 0.5, 0.5, 1.7)])
    box = _image_box(12.0, 0.0, 0.5, 0.5, 1.7)
    det = CameraDetections(
        stamp=Stamp(0),
        camera_id="front",
        boxes=np.array([[*box, int(ObjectClass.PEDESTRIAN), 0.8]], dtype=np.float32),
    )
    out = fuse(Stamp(0), cs, (), None, [CAM], [det], map_from_base=SE2(100.0, 50.0, math.pi / 2))
    assert out.frame == "map"
    t = out.table
    ped = np.argmin(np.hypot(t[:, 0] - 100.0, t[:, 1] - 62.0))  # (12, 0) in base -> map
    assert t[ped, 7] == ObjectClass.PEDESTRIAN
    assert (t[:, 7] == ObjectClass.PEDESTRIAN).sum() == 1


def test_pedestrian_candidates_are_verified_only_by_an_overlapping_pedestrian_box():
    cs = _clusters([(12.0, 2.0, 0.5, 0.5, 1.7), (15.0, -3.0, 0.5, 0.5, 1.7), (9.0, 0.0, 4.0, 1.8, 1.4)])
    box = _image_box(12.0, 2.0, 0.5, 0.5, 1.7)
    det = CameraDetections(
        stamp=Stamp(0),
        camera_id="front",
        boxes=np.array([[*box, int(ObjectClass.PEDESTRIAN), 0.9]], dtype=np.float32),
    )
    res = verify_pedestrians(cs, CAM, det)
    xs = cs.table[res.rows, 0]
    assert sorted(np.round(xs).tolist()) == [12.0, 15.0]  # the car is no candidate
    assert res.in_view.all()
    assert res.verified[np.argmin(np.abs(xs - 12))] and not res.verified[np.argmin(np.abs(xs - 15))]
    with pytest.raises(ConfigError, match="expected detections from camera"):
        verify_pedestrians(
            cs, CAM, CameraDetections(stamp=Stamp(0), camera_id="rear", boxes=np.zeros((0, 6)))
        )


def test_iou_and_bad_inputs():
    assert box_iou([[0, 0, 2, 2]], [[1, 1, 3, 3], [5, 5, 6, 6]]).tolist() == [[1 / 7, 0.0]]
    with pytest.raises(MessageError, match="mounting for radar"):
        fuse(Stamp(0), _clusters([(10, 0, 1, 1, 1)]), [RadarFrame(stamp=Stamp(0), sensor_id="rear")], {})
    with pytest.raises(ConfigError, match="rotation"):
        PinholeCamera(
            camera_id="c", fx_px=1.0, fy_px=1.0, cx_px=0.0, cy_px=0.0, width_px=10, height_px=10,
            camera_from_base=np.diag([2.0, 1, 1, 1]),
        )  # fmt: skip


def test_radar_only_objects_are_dropped_unless_asked_for():
    cs = _clusters([(15.0, 0.0, 4.4, 1.8, 1.5)])
    ghost = RadarFrame(stamp=Stamp(0), sensor_id="front", objects=np.array([[30.0, 5.0, 2.0, 0.0, 5.0, 2.0]]))
    mounts = {"front": SE2(4.5, 0.0, 0.0)}
    assert len(fuse(Stamp(0), cs, [ghost], mounts)) == 1
    out = fuse(Stamp(0), cs, [ghost], mounts, config=LateFusionConfig(keep_radar_only=True))
    assert len(out) == 2
    extra = out.table[np.argmax(out.table[:, 0])]
    assert extra[0] == 34.5 and extra[2] == 2.0 and extra[7] == ObjectClass.UNKNOWN


def test_nus_verification_names_pedestrians_only_person_shaped_verified_clusters():
    # A person, and a knee-high post a camera pedestrian box also falls on (a false detection, or a
    # pedestrian the LiDAR sees only in part): WATonoBus's boxes name both, NUS only the person.
    cs = _clusters([(12.0, 2.0, 0.5, 0.5, 1.7), (10.0, -2.0, 0.5, 0.5, 0.6), (18.0, 0.0, 4.4, 1.8, 1.5)])
    boxes = [_image_box(12.0, 2.0, 0.5, 0.5, 1.7), _image_box(10.0, -2.0, 0.5, 0.5, 0.6)]
    car_box = _image_box(18.0, 0.0, 4.4, 1.8, 1.5)
    det = CameraDetections(
        stamp=Stamp(0),
        camera_id="front",
        boxes=np.array(
            [*[[*b, int(ObjectClass.PEDESTRIAN), 0.9] for b in boxes], [*car_box, int(ObjectClass.CAR), 0.9]],
            dtype=np.float32,
        ),
    )

    def classes(config: LateFusionConfig) -> list[int]:
        t = fuse(Stamp(0), cs, (), None, [CAM], [det], config=config).table
        return [
            int(t[np.argmin(np.hypot(t[:, 0] - x, t[:, 1] - y)), 7]) for x, y in ((12, 2), (10, -2), (18, 0))
        ]

    ped, unk, car = int(ObjectClass.PEDESTRIAN), int(ObjectClass.UNKNOWN), int(ObjectClass.CAR)
    assert classes(LateFusionConfig()) == [ped, ped, car]
    nus = LateFusionConfig(pedestrian_verification=PedestrianVerificationConfig())
    assert classes(nus) == [ped, unk, car]  # other classes stay the camera's
    # Without a camera pedestrian box nobody is verified, however person-shaped.
    no_ped = CameraDetections(stamp=Stamp(0), camera_id="front", boxes=det.boxes[2:])
    t = fuse(Stamp(0), cs, (), None, [CAM], [no_ped], config=nus).table
    assert int(ObjectClass.PEDESTRIAN) not in t[:, 7].astype(int).tolist()
