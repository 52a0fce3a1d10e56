"""Readers of real point-cloud files, the ring and time a sensor model derives, and ``lastmile perceive``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from lastmile.cli import app
from lastmile.core.config import from_mapping
from lastmile.core.errors import ConfigError, MessageError
from lastmile.perception.cloud_files import read_clouds, sweep_from_cloud
from lastmile.perception.lidar_model import (
    LidarModel,
    LidarSensorConfig,
    RingSource,
    TimeSource,
    ring_from_elevation,
    time_from_azimuth,
)
from lastmile.perception.perceive import PerceiveConfig, load_perceive_config, perceive_files
from tests.perception import cloud_fixtures as fx

VLP16 = LidarSensorConfig(sensor_id="top", model=LidarModel(name="vlp16", azimuth_resolution_deg=2.0))


@pytest.fixture(scope="module")
def scan():
    return fx.spinning_scan()


def _xyz(scan):
    return np.c_[scan["x"], scan["y"], scan["z"]]


def test_ring_from_elevation_recovers_every_beam_of_a_vlp16(scan):
    ring = ring_from_elevation(_xyz(scan), VLP16.model)
    np.testing.assert_array_equal(ring, scan["ring"])


def test_ring_from_elevation_bins_a_model_known_only_by_its_field_of_view(scan):
    model = LidarModel(name="custom", rings=16, min_elevation_deg=-16.0, max_elevation_deg=16.0,
                       azimuth_resolution_deg=0.2)  # fmt: skip
    np.testing.assert_array_equal(ring_from_elevation(_xyz(scan), model), scan["ring"])


def test_a_cloud_that_does_not_fit_the_model_is_refused_naming_the_file(scan):
    narrow = LidarModel(name="custom", beam_elevations_deg=(-1.0, 0.0, 1.0), azimuth_resolution_deg=0.2)
    with pytest.raises(MessageError, match=r"scan\.bin: expected elevations within -1\.0\.\.1\.0 deg"):
        ring_from_elevation(_xyz(scan), narrow, "scan.bin")


def test_time_from_azimuth_gives_each_column_its_firing_time(scan):
    t_us = time_from_azimuth(_xyz(scan), VLP16.model)
    np.testing.assert_allclose(t_us, scan["time"].astype(np.float64) * 1e6, atol=1.0)
    ccw = LidarModel(name="vlp16", azimuth_resolution_deg=2.0, clockwise=False, sweep_start_azimuth_deg=0.0)
    t_ccw = time_from_azimuth(np.array([[1.0, 0.01, 0.0], [0.0, 1.0, 0.0], [-1.0, -0.01, 0.0]]), ccw)
    np.testing.assert_allclose(t_ccw, [0.0, 25_000.0, 50_000.0], atol=1.0)


def test_kitti_bin_without_ring_or_time_gets_both_from_the_model(tmp_path, scan):
    path = fx.write_kitti_bin(tmp_path / "000007.bin", scan)
    (cloud,) = read_clouds(path)
    assert cloud.ring is None and cloud.t_offset_us is None
    np.testing.assert_allclose(cloud.intensity, scan["intensity"], atol=1e-3)  # 0..1 read as 0..255
    sweep, prov = sweep_from_cloud(cloud, VLP16)
    assert (prov.ring, prov.time, prov.intensity) == ("elevation", "azimuth", "file")
    np.testing.assert_array_equal(sweep.points[:, 4], scan["ring"])
    np.testing.assert_allclose(sweep.points[:, 5], scan["time"] * 1e6, atol=1.0)
    whole, prov = sweep_from_cloud(cloud, LidarSensorConfig(model=VLP16.model, time=TimeSource.SWEEP))
    assert prov.time == "sweep stamp" and not whole.points[:, 5].any()


def test_kitti_bin_of_the_wrong_size_or_with_nan_is_refused(tmp_path, scan):
    bad = tmp_path / "short.bin"
    bad.write_bytes(b"\0" * 20)
    with pytest.raises(MessageError, match=r"short\.bin: expected float32 rows .* got 20 bytes"):
        list(read_clouds(bad))
    a = np.zeros((3, 4), "<f4")
    a[1, 2] = np.nan
    a.tofile(tmp_path / "nan.bin")
    with pytest.raises(MessageError, match=r"nan\.bin: z: expected finite values, got nan at point 1"):
        list(read_clouds(tmp_path / "nan.bin"))
    with pytest.raises(MessageError, match=r"expected a \.bin \(KITTI\), \.pcd or \.mcap file"):
        list(read_clouds(fx.write_kitti_bin(tmp_path / "scan.txt", scan)))


def test_pcd_with_ring_and_time_fields_keeps_them(tmp_path, scan):
    path = fx.write_pcd(tmp_path / "a.pcd", scan, ("x", "y", "z", "intensity", "ring", "time"))
    (cloud,) = read_clouds(path)
    sweep, prov = sweep_from_cloud(cloud, VLP16)
    assert (prov.ring, prov.time) == ("file", "file")
    np.testing.assert_array_equal(sweep.points[:, 4], scan["ring"])
    np.testing.assert_allclose(sweep.points[:, 5], scan["time"].astype(np.float64) * 1e6, rtol=1e-6)
    np.testing.assert_array_equal(sweep.points[:, 3], scan["intensity"])


def test_pcd_without_ring_derives_it_and_a_required_ring_field_is_refused(tmp_path, scan):
    path = fx.write_pcd(tmp_path / "b.pcd", scan, ("x", "y", "z"))
    (cloud,) = read_clouds(path)
    sweep, prov = sweep_from_cloud(cloud, VLP16)
    assert (prov.ring, prov.time, prov.intensity) == ("elevation", "azimuth", "absent (0)")
    np.testing.assert_array_equal(sweep.points[:, 4], scan["ring"])
    strict = LidarSensorConfig(model=VLP16.model, ring=RingSource.FIELD)
    with pytest.raises(MessageError, match=r"b\.pcd: expected a 'ring' field \(sensor\.ring = 'field'\)"):
        sweep_from_cloud(cloud, strict)


def test_pcd_without_z_is_refused_naming_the_field(tmp_path, scan):
    path = fx.write_pcd(tmp_path / "c.pcd", scan, ("x", "y", "intensity"))
    with pytest.raises(MessageError, match=r"c\.pcd: expected fields x, y, z, got .*missing \['z'\]"):
        list(read_clouds(path))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_rosbag2_pointcloud2_messages_are_read_in_order_with_their_stamps(tmp_path, scan, storage):
    stamps = [1_700_000_000_000_000_000, 1_700_000_000_100_000_000]
    bag = fx.write_rosbag2(tmp_path / "bag", scan, ("x", "y", "z", "intensity", "ring"), stamps, storage)
    clouds = list(read_clouds(bag))
    assert [c.stamp_us for c in clouds] == [s // 1000 for s in stamps]
    assert clouds[0].name == "bag:/points[0]"
    np.testing.assert_array_equal(clouds[1].xyz_m, _xyz(scan))
    np.testing.assert_array_equal(clouds[1].ring, scan["ring"])
    with pytest.raises(MessageError, match=r"expected topic '/lidar' of type sensor_msgs/msg/PointCloud2"):
        list(read_clouds(bag, "/lidar"))


def test_bare_mcap_pointcloud2_is_read(tmp_path, scan):
    path = fx.write_bare_mcap(
        tmp_path / "one.mcap", scan, ("x", "y", "z", "intensity", "time"), 5_000_000_000
    )
    (cloud,) = read_clouds(path)
    assert cloud.stamp_us == 5_000_000
    np.testing.assert_array_equal(cloud.xyz_m, _xyz(scan))
    np.testing.assert_allclose(cloud.t_offset_us, scan["time"].astype(np.float64) * 1e6)


def test_perceive_config_is_strict(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[sensor]\nsensor_id = "top"\nring = "sideways"\n')
    with pytest.raises(
        ConfigError, match=r"sensor\.ring: expected one of \['auto', 'field', 'elevation', 'scan_order'\]"
    ):
        load_perceive_config(cfg)
    cfg.write_text("[sensor.mount]\nz_m = 1.5\nheight_m = 2\n")
    with pytest.raises(ConfigError, match=r"sensor\.mount: unknown key 'height_m'"):
        load_perceive_config(cfg)
    cfg.write_text('topic = "/points"\n[sensor.model]\nname = "vlp16"\n[sensor.mount]\nz_m = 1.5\n'
                   '[pipeline]\nground = "himmelsbach"\n')  # fmt: skip
    loaded = load_perceive_config(cfg)
    assert loaded.sensor.model.name == "vlp16" and loaded.sensor.mount.z_m == 1.5
    assert loaded.pipeline.ground == "himmelsbach" and loaded.topic == "/points"


def test_perceive_finds_the_box_and_writes_labels_mcap_and_timing(tmp_path, scan):
    from mcap.reader import make_reader

    bin_path = fx.write_kitti_bin(tmp_path / "000001.bin", scan)
    bag = fx.write_rosbag2(tmp_path / "bag", scan, ("x", "y", "z", "intensity", "ring", "time"),
                           [2_000_000_000], "sqlite3")  # fmt: skip
    config = from_mapping(
        PerceiveConfig,
        {"sensor": {"sensor_id": "top", "model": {"name": "vlp16", "azimuth_resolution_deg": 2.0},
                    "mount": {"z_m": fx.SENSOR_HEIGHT_M}},
         "pipeline": {"crop": {"ego_x_min_m": -0.5, "ego_x_max_m": 0.5, "ego_half_width_m": 0.5}}},
        "test",
    )  # fmt: skip
    out = tmp_path / "out"
    frames = perceive_files([bin_path, bag], config, out)
    assert [f.provenance.ring for f in frames] == ["elevation", "file"]
    for k in range(2):
        rows = [line.split() for line in (out / "labels" / f"{k:06d}.txt").read_text().splitlines()]
        # The box's face: 6 m ahead (KITTI camera z), centred (x), 1 m wide; the beams at 6 m see
        # it from 0.33 m (-11 deg) to 1.40 m (-1 deg) above the road.
        near = [r for r in rows if abs(float(r[13]) - 6.0) < 0.3 and abs(float(r[11])) < 0.3]
        assert len(near) == 1, rows
        assert len(near[0]) == 16 and near[0][0] == "Misc"
        assert 1.0 < float(near[0][8]) < 1.1 and 0.8 < float(near[0][10]) + float(near[0][9]) < 1.3
    timing = json.loads((out / "timing.json").read_text())
    assert [t["source"] for t in timing] == ["000001.bin", "bag:/points[0]"]
    assert all(t["stage_ms"]["total"] > 0 for t in timing)
    with open(out / "objects.mcap", "rb") as handle:
        summary = make_reader(handle).get_summary()
    schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert schemas == {"/lidar/points": "foxglove.PointCloud", "/perception/objects": "foxglove.SceneUpdate"}
    assert sum(summary.statistics.channel_message_counts.values()) == 4


def test_perceive_cli_reports_a_bad_file_in_one_line(tmp_path):
    bad = tmp_path / "x.pcd"
    bad.write_text("not a pcd")
    result = CliRunner().invoke(app, ["perceive", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert result.output.strip().startswith("lastmile perceive: ")
    assert "x.pcd: expected a PCD file" in result.output and "Traceback" not in result.output


def test_ring_from_scan_order_recovers_the_beams_of_a_cloud_listed_beam_by_beam(scan):
    from lastmile.perception.lidar_model import ring_from_scan_order

    xyz = _xyz(scan)
    # Beam by beam, top beam first, each in firing order (clockwise from behind, as the model says).
    order = np.lexsort((scan["time"], -scan["ring"].astype(np.int64)))
    got = ring_from_scan_order(xyz[order], VLP16.model, "beams.bin")
    np.testing.assert_array_equal(got, scan["ring"][order])
    # Listed column by column instead: one "beam" spanning every elevation.
    with pytest.raises(MessageError, match=r"columns\.bin: expected each beam's returns listed together"):
        ring_from_scan_order(xyz, VLP16.model, "columns.bin")
    with pytest.raises(MessageError, match=r"shuffled\.bin: expected at most 16 beams"):
        ring_from_scan_order(xyz[np.random.default_rng(0).permutation(len(xyz))], VLP16.model, "shuffled.bin")
