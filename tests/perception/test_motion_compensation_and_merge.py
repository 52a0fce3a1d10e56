"""De-skewing puts a moving bus's points where they are at the reference time; merge uses extrinsics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from lastmile.core.errors import MessageError
from lastmile.core.sensor_frames import GnssInsFrame, LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.perception.merge import merge_sweeps
from lastmile.perception.motion_compensation import PoseTrajectory, deskew_points, se3_matrix
from tests.perception.synthetic import Box, Scene, default_rig, sweep


def _trajectory(speed: float, yaw_rate: float, t0: int = -100_000, t1: int = 250_000) -> PoseTrajectory:
    ts = np.arange(t0, t1 + 1, 10_000)  # 100 Hz INS
    t = ts / 1e6
    yaw = yaw_rate * t
    if abs(yaw_rate) < 1e-9:
        x, y = speed * t, 0.0 * t
    else:
        x, y = speed / yaw_rate * np.sin(yaw), speed / yaw_rate * (1 - np.cos(yaw))
    return PoseTrajectory(
        stamps_us=ts,
        xyz_m=np.c_[x, y, np.zeros_like(t)],
        quat_xyzw=Rotation.from_euler("z", np.asarray(yaw)[:, None]).as_quat(),
    )


def test_wall_seen_while_driving_is_straight_and_in_place_after_deskew():
    # A wall 10 m ahead, across the road; the bus drives at 8 m/s during a 100 ms sweep.
    wall = Box((10.0, -20.0, 0.0), (10.5, 20.0, 3.0))
    scene = Scene(profile_y=(-30.0, 30.0), profile_z=(-5.0, -5.0), boxes=(wall,))
    lidar = default_rig()[0]
    sw, box = sweep(scene, lidar, 0, np.random.default_rng(0), ego_speed_mps=8.0, range_noise_m=0.0)
    traj = _trajectory(8.0, 0.0)
    ref = 100_000
    t = int(sw.stamp) + sw.points[:, 5].astype(np.int64)
    fixed = deskew_points(sw.points[:, :3], t, traj, lidar.base_from_sensor, ref, time_bin_us=100)
    raw = (
        sw.points[:, :3] @ lidar.base_from_sensor[:3, :3].T.astype(np.float32) + lidar.base_from_sensor[:3, 3]
    )
    face = (box == 0) & (np.abs(raw[:, 1]) < 15)
    # At the reference time the bus has moved 0.8 m: the wall face is at x = 10 - 0.8 in the base frame.
    assert np.abs(fixed[face, 0] - 9.2).max() < 0.01
    assert np.ptp(raw[face, 0]) > 0.3  # uncompensated, the face smears over the sweep


@settings(max_examples=25, deadline=None)
@given(
    speed=st.floats(0.0, 10.0),
    yaw_rate=st.floats(-0.8, 0.8),
    t_ref=st.integers(0, 100_000),
)
def test_deskew_inverts_the_motion_for_any_planar_trajectory(speed, yaw_rate, t_ref):
    traj = _trajectory(speed, yaw_rate)
    rng = np.random.default_rng(0)
    world = rng.uniform(-30, 30, (200, 3))  # static points in the map frame
    t = rng.integers(0, 100_000, 200)
    B = se3_matrix(1.5, -1.1, 0.9, 0.0, 0.0, -math.pi / 2)
    M = traj.matrices_at(t)
    # Sensor-frame observation of each world point at its own time.
    sensor_from_map = np.linalg.inv(M @ B)
    p_sensor = np.einsum("nij,nj->ni", sensor_from_map[:, :3, :3], world) + sensor_from_map[:, :3, 3]
    out = deskew_points(p_sensor, t, traj, B, t_ref, time_bin_us=1)
    base_ref_from_map = np.linalg.inv(traj.matrices_at([t_ref])[0])
    expect = world @ base_ref_from_map[:3, :3].T + base_ref_from_map[:3, 3]
    assert np.abs(out - expect).max() < 2e-3  # float32 output at tens of metres


def test_stale_ins_raises_instead_of_bending_the_cloud():
    traj = _trajectory(5.0, 0.0, 0, 50_000)
    with pytest.raises(MessageError, match="query times"):
        traj.matrices_at([500_000])


def test_trajectory_from_ins_rejects_outages_and_unwraps_yaw():
    frames = [
        GnssInsFrame(stamp=Stamp(0), x_m=0, y_m=0, yaw_rad=3.1, speed_mps=1, pos_std_m=0.1, yaw_std_rad=0.1),
        GnssInsFrame(
            stamp=Stamp(100_000), x_m=0.1, y_m=0, yaw_rad=-3.1, speed_mps=1, pos_std_m=0.1, yaw_std_rad=0.1
        ),
    ]
    traj = PoseTrajectory.from_ins(frames)
    mid = Rotation.from_matrix(traj.matrices_at([50_000])[0, :3, :3]).as_euler("zyx")[0]
    assert abs(abs(mid) - math.pi) < 0.01  # through pi, not through 0
    bad = [
        *frames[:1],
        GnssInsFrame(
            stamp=Stamp(1), x_m=0, y_m=0, yaw_rad=0, speed_mps=0, pos_std_m=1, yaw_std_rad=1, fix_ok=False
        ),
    ]
    with pytest.raises(MessageError, match="outages"):
        PoseTrajectory.from_ins(bad)


def test_merge_applies_each_extrinsic_and_tags_the_sensor():
    pts = np.array([[1.0, 0.0, 0.0, 50, 3, 0]], dtype=np.float32)
    sweeps = [LidarSweep(stamp=Stamp(0), sensor_id=s, points=pts) for s in ("front", "left")]
    ext = {"front": se3_matrix(4, 0, 2, 0, 0, 0), "left": se3_matrix(1, 1, 1, 0, 0, math.pi / 2)}
    m = merge_sweeps(sweeps, ext)
    m.validate()
    assert np.allclose(m.points[0, :3], [5, 0, 2]) and np.allclose(m.points[1, :3], [1, 2, 1], atol=1e-6)
    assert m.points[:, 5].tolist() == [0, 1] and m.points[1, 3] == 50 and not m.compensated
    with pytest.raises(MessageError, match="extrinsics for every sensor"):
        merge_sweeps(sweeps, {"front": ext["front"]})
    with pytest.raises(MessageError, match="distinct sensor ids"):
        merge_sweeps([sweeps[0], sweeps[0]], ext)


@settings(max_examples=25, deadline=None)
@given(
    speed=st.floats(0.0, 8.0),
    yaw_rate=st.floats(-0.5, 0.5),
    bin_us=st.sampled_from([1, 100, 500, 2000]),
    empty=st.integers(-1, 2),
)
def test_merge_with_poses_equals_each_sweep_deskewed_on_its_own_bit_for_bit(speed, yaw_rate, bin_us, empty):
    # merge_sweeps queries the poses once for every sweep; the points must be exactly those of
    # one deskew_points call per sweep (an empty sweep included).
    rng = np.random.default_rng(int(speed * 1000) + bin_us)
    traj = _trajectory(speed, yaw_rate)
    ext = {
        "front": se3_matrix(3.9, 0.0, 2.1, 0.0, 0.02, 0.0),
        "left": se3_matrix(1.0, 1.1, 1.9, 0.0, 0.0, math.pi / 2),
        "right": se3_matrix(1.0, -1.1, 1.9, 0.0, 0.0, -math.pi / 2),
    }
    sweeps = []
    for k, sid in enumerate(ext):
        n = 0 if k == empty else 500
        pts = np.c_[
            rng.uniform(-30, 30, (n, 3)),
            rng.uniform(0, 255, n),
            rng.integers(0, 32, n),
            rng.uniform(0, 99_999, n),
        ].astype(np.float32)
        sweeps.append(LidarSweep(stamp=Stamp(10_000 * k), sensor_id=sid, points=pts))
    m = merge_sweeps(sweeps, ext, traj, time_bin_us=bin_us)
    ref = int(m.stamp)
    parts = [
        deskew_points(
            s.points[:, :3],
            int(s.stamp) + s.points[:, 5].astype(np.int64),
            traj,
            ext[s.sensor_id],
            ref,
            bin_us,
        )
        for s in sweeps
    ]
    assert m.compensated and np.array_equal(m.points[:, :3], np.concatenate(parts))
    assert m.points[:, 5].tolist() == [k for k, s in enumerate(sweeps) for _ in range(len(s.points))]
