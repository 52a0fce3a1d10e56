"""Drive readers: documented CSV, rosbag2 (MCAP) written with rosbags, the real ROS 1 bag, assembly in ENU."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lastmile.core.gnss_messages import GnssQuality
from lastmile.recorder.drive_csv import read_drive_csv
from lastmile.recorder.drive_reader import read_drive
from lastmile.recorder.drive_rosbag import BagTopics, read_rosbag
from lastmile.recorder.recorded_drive import DriveFormatError

HUSKY_BAG = (
    Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "drives" / "husky_robot_localization"
)
HUSKY_BAG = HUSKY_BAG / "test1.bag"


def test_csv_streams_are_recognised_by_their_header_with_exact_microseconds(tmp_path):
    imu = tmp_path / "imu.csv"
    imu.write_text("t_s,yaw_rate_radps,accel_x_mps2\n1700000000.000001,0.1,0.2\n1700000000.010001,0.1,0.3\n")
    wheel = tmp_path / "wheel.csv"
    wheel.write_text("t_s,speed_mps\n1700000000.02,1.5\n")
    gnss = tmp_path / "gnss.csv"
    gnss.write_text(
        "t_s,lat_deg,lon_deg,height_m,std_east_m,std_north_m,quality\n1700000000.25,43.47,-80.54,300,0.01,0.02,rtk_fixed\n"
    )
    stream = read_drive_csv(imu).imu
    assert stream is not None and stream.utc_us.tolist() == [1_700_000_000_000_001, 1_700_000_000_010_001]
    assert stream.accel_x_mps2.tolist() == [0.2, 0.3]
    assert read_drive_csv(wheel).wheel.speed_mps.tolist() == [1.5]
    (fix,) = read_drive_csv(gnss).fixes
    assert fix.quality is GnssQuality.RTK_FIXED and fix.var_n_m2 == pytest.approx(0.02**2)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("t_s,speed\n1,2\n", r"x\.csv:1: expected one of the headers"),
        (
            "t_s,speed_mps\n1700000000.0,fast\n",
            r"x\.csv:2, column 2 \(speed_mps\): expected a number, got 'fast'",
        ),
        ("t_s,speed_mps\n1700000000.0,1\n1700000000.1\n", r"x\.csv:3: expected 2 columns, got 1"),
        ("t_s,speed_mps\n17e8,1\n", r"x\.csv:2, column 1 \(t_s\): expected seconds"),
        ("t_s,speed_mps\n1700000000.5,1\n1700000000.4,1\n", r"x\.csv:3, column 1 \(t_s\): expected times in"),
        (
            "t_s,lat_deg,lon_deg,height_m,std_east_m,std_north_m,quality\n1700000000,43,-80,300,0.01,0.01,fixed\n",
            r"x\.csv:2, column 7 \(quality\): expected one of rtk_fixed",
        ),
        ("t_s,yaw_rate_radps\n1700000000,nan\n", r"x\.csv:2, column 2 \(yaw_rate_radps\): expected a finite"),
    ],
)
def test_csv_errors_name_the_line_and_column(tmp_path, text, match):
    path = tmp_path / "x.csv"
    path.write_text(text)
    with pytest.raises(DriveFormatError, match=match):
        read_drive_csv(path)


def _write_rosbag2(path: Path, tilt_rad: float) -> None:
    """A rosbag2 (MCAP) with an IMU mounted pitched up by ``tilt_rad``, a NavSatFix and wheel odometry."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    t = ts.types
    header = lambda k: t["std_msgs/msg/Header"](  # noqa: E731
        stamp=t["builtin_interfaces/msg/Time"](sec=1_700_000_000 + k // 100, nanosec=(k % 100) * 10_000_000),
        frame_id="base_link",
    )
    vec = t["geometry_msgs/msg/Vector3"]
    c, s = math.cos(tilt_rad), math.sin(tilt_rad)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        imu_c = writer.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
        fix_c = writer.add_connection("/gps/fix", "sensor_msgs/msg/NavSatFix", typestore=ts)
        odom_c = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        for k in range(300):
            # Vehicle frame: yaw rate 0.1 rad/s, forward acceleration 0.5, gravity up; the IMU frame is
            # the vehicle's pitched by tilt about y.
            w_v, a_v = np.array([0.0, 0.0, 0.1]), np.array([0.5, 0.0, 9.80665])
            rot = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
            w_i, a_i = rot @ w_v, rot @ a_v
            imu = t["sensor_msgs/msg/Imu"](
                header=header(k),
                orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.full(9, -1.0),
                angular_velocity=vec(x=w_i[0], y=w_i[1], z=w_i[2]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vec(x=a_i[0], y=a_i[1], z=a_i[2]),
                linear_acceleration_covariance=np.zeros(9),
            )
            stamp_ns = 1_700_000_000_000_000_000 + k * 10_000_000
            writer.write(imu_c, stamp_ns, ts.serialize_cdr(imu, "sensor_msgs/msg/Imu"))
            if k % 25 == 0:
                status = t["sensor_msgs/msg/NavSatStatus"](status=-1 if k == 275 else 2, service=1)
                fix = t["sensor_msgs/msg/NavSatFix"](
                    header=header(k),
                    status=status,
                    latitude=43.47 + k * 1e-7,
                    longitude=-80.54,
                    altitude=300.0,
                    position_covariance=np.array([1e-4, 0, 0, 0, 4e-4, 0, 0, 0, 1e-3]),
                    position_covariance_type=2,
                )
                writer.write(fix_c, stamp_ns, ts.serialize_cdr(fix, "sensor_msgs/msg/NavSatFix"))
            if k % 2 == 0:
                odom = t["nav_msgs/msg/Odometry"](
                    header=header(k),
                    child_frame_id="base_link",
                    pose=t["geometry_msgs/msg/PoseWithCovariance"](
                        pose=t["geometry_msgs/msg/Pose"](
                            position=t["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                        ),
                        covariance=np.zeros(36),
                    ),
                    twist=t["geometry_msgs/msg/TwistWithCovariance"](
                        twist=t["geometry_msgs/msg/Twist"](
                            linear=vec(x=2.0, y=0.0, z=0.0), angular=vec(x=0, y=0, z=0.1)
                        ),
                        covariance=np.zeros(36),
                    ),
                )
                writer.write(odom_c, stamp_ns, ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))


def test_a_rosbag2_mcap_drive_with_a_tilted_imu_is_levelled(tmp_path):
    bag = tmp_path / "drive"
    _write_rosbag2(bag, tilt_rad=math.radians(20.0))
    streams = read_rosbag(bag)
    assert streams.imu is not None and streams.wheel is not None
    # The up axis comes from the mean specific force: the small forward acceleration tips it by
    # atan(0.5 / 9.8) = 2.9 deg, so the yaw rate reads cos(2.9 deg) of the truth.
    assert streams.imu.yaw_rate_radps == pytest.approx(0.1 * math.cos(math.atan(0.5 / 9.80665)), rel=1e-6)
    assert streams.wheel.speed_mps.tolist() == [2.0] * 150
    assert len(streams.fixes) == 11 and streams.skipped_no_fix == 1
    fix = streams.fixes[0]
    assert (fix.var_e_m2, fix.var_n_m2) == (1e-4, 4e-4) and fix.quality is GnssQuality.RTK_FIXED
    drive = read_drive([bag / "drive.mcap"])  # the .mcap file itself reads too
    assert drive.fixes[0].stamp == 0 and drive.imu_us[0] == 0
    north = [f.y_m for f in drive.fixes]
    assert north[1] - north[0] == pytest.approx(25e-7 * math.pi / 180 * 6_367_000, rel=0.01)


def test_bag_errors_name_the_topic(tmp_path):
    bag = tmp_path / "drive"
    _write_rosbag2(bag, tilt_rad=0.0)
    with pytest.raises(
        DriveFormatError,
        match=r"expected topic '/fix' of type sensor_msgs/msg/NavSatFix, found \['/gps/fix'\]",
    ):
        read_rosbag(bag, BagTopics(fix="/fix"))
    with pytest.raises(DriveFormatError, match="IMU axis given as forward is within 60 deg of its up axis"):
        read_rosbag(bag, forward_axis="z")
    with pytest.raises(DriveFormatError, match=r"expected a \.pos \(RTKLIB\)"):
        read_drive([tmp_path / "drive.txt"])


@pytest.mark.skipif(not HUSKY_BAG.exists(), reason=f"real ROS 1 bag not found at {HUSKY_BAG}")
def test_the_real_husky_ros1_bag_reads_every_stream():
    drive = read_drive([HUSKY_BAG])
    assert len(drive.fixes) == 989 and drive.imu_us.size == 11_865 and drive.wheel_us.size == 3_952
    assert {f.quality for f in drive.fixes} == {GnssQuality.DGNSS}  # NavSatStatus 1 (SBAS)
    assert (np.diff(drive.imu_us) > 0).all()
    # Its IMU is mounted with y up (gravity on +y): levelled, its yaw rate is a few hundredths of rad/s.
    assert np.percentile(np.abs(drive.imu_yaw_rate_radps), 50) < 0.1
    span = np.ptp([f.x_m for f in drive.fixes]), np.ptp([f.y_m for f in drive.fixes])
    assert 10.0 < max(span) < 500.0  # metres, not degrees
