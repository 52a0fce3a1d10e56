"""Tiny point-cloud files the reader tests build themselves: KITTI .bin, PCD, rosbag2 and bare MCAP."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lastmile.perception.lidar_model import VLP16_ELEVATIONS_DEG

SENSOR_HEIGHT_M = 1.5
COLUMN_STEP_DEG = 2.0  # coarse columns keep the files tiny


def spinning_scan() -> dict[str, np.ndarray]:
    """A VLP-16-like sweep (16 rings x 180 columns, clockwise from behind, 10 Hz) over flat ground
    1.5 m below with a 1 x 1 x 1.6 m box 6 m ahead; every ring and firing time known."""
    cols = np.arange(int(360 / COLUMN_STEP_DEG))
    az = np.radians(180.0 - cols * COLUMN_STEP_DEG)  # clockwise from behind
    el = np.radians(np.asarray(VLP16_ELEVATIONS_DEG))
    A, E = np.meshgrid(az, el, indexing="ij")
    C, R = np.meshgrid(cols, np.arange(len(el)), indexing="ij")
    down = np.tan(-E)
    rng = np.where(down > 1e-3, SENSOR_HEIGHT_M / np.maximum(down, 1e-3), 40.0)
    rng = np.minimum(rng, 40.0)
    ux, uy = np.cos(A), np.sin(A)
    # The box's front face at x = 6 m, |y| <= 0.5, up to 0.1 m above the sensor.
    t_box = 6.0 / np.maximum(ux, 1e-9)
    hit = (ux > 0) & (np.abs(uy * t_box) <= 0.5) & (t_box < rng) & (np.tan(E) * t_box <= 0.1)
    hit &= np.tan(E) * t_box >= -SENSOR_HEIGHT_M
    rng = np.where(hit, t_box, rng)
    x, y, z = rng * ux, rng * uy, rng * np.tan(E)  # rng: horizontal range
    period_us = 100_000.0
    t = C * period_us * COLUMN_STEP_DEG / 360.0
    return {
        "x": x.ravel().astype(np.float32),
        "y": y.ravel().astype(np.float32),
        "z": z.ravel().astype(np.float32),
        "intensity": np.full(x.size, 40.0, dtype=np.float32),
        "ring": R.ravel().astype(np.uint16),
        "time": (t.ravel() * 1e-6).astype(np.float32),  # velodyne_pointcloud: seconds
    }


def write_kitti_bin(path: Path, scan: dict[str, np.ndarray]) -> Path:
    np.c_[scan["x"], scan["y"], scan["z"], scan["intensity"] / 255.0].astype("<f4").tofile(path)
    return path


def write_pcd(path: Path, scan: dict[str, np.ndarray], fields: tuple[str, ...]) -> Path:
    from pypcd4 import PointCloud

    types = [scan[f].dtype.type for f in fields]
    PointCloud.from_points([scan[f] for f in fields], fields, types).save(path)
    return path


def _pointcloud2(store, scan: dict[str, np.ndarray], fields: tuple[str, ...], stamp_ns: int):  # type: ignore[no-untyped-def]
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    PointField = store.types["sensor_msgs/msg/PointField"]
    PointCloud2 = store.types["sensor_msgs/msg/PointCloud2"]
    code = {np.dtype("float32"): 7, np.dtype("uint16"): 4}
    dtype = np.dtype([(f, scan[f].dtype) for f in fields])
    rec = np.zeros(len(scan["x"]), dtype=dtype)
    for f in fields:
        rec[f] = scan[f]
    pf = [
        PointField(name=f, offset=dtype.fields[f][1], datatype=code[scan[f].dtype], count=1) for f in fields
    ]
    return PointCloud2(
        header=Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id="lidar"),
        height=1,
        width=len(rec),
        fields=pf,
        is_bigendian=False,
        point_step=dtype.itemsize,
        row_step=dtype.itemsize * len(rec),
        data=np.frombuffer(rec.tobytes(), dtype=np.uint8),
        is_dense=True,
    )


def write_rosbag2(
    path: Path, scan: dict[str, np.ndarray], fields: tuple[str, ...], stamps_ns: list[int], storage: str
) -> Path:
    """A rosbag2 directory (``storage`` "sqlite3" or "mcap") with one PointCloud2 per stamp on ``/points``
    and an unrelated ``/chatter`` topic."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.LATEST)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        conn = writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=store)
        chatter = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        String = store.types["std_msgs/msg/String"]
        writer.write(chatter, stamps_ns[0], store.serialize_cdr(String(data="hi"), "std_msgs/msg/String"))
        for ns in stamps_ns:
            msg = _pointcloud2(store, scan, fields, ns)
            writer.write(conn, ns, store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    return path


def write_bare_mcap(path: Path, scan: dict[str, np.ndarray], fields: tuple[str, ...], stamp_ns: int) -> Path:
    """A bare MCAP file (cdr-encoded ROS 2 message, ros2msg schema) with one PointCloud2 on ``/points``."""
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.LATEST)
    msg = _pointcloud2(store, scan, fields, stamp_ns)
    schema_text = (
        "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\nbool is_bigendian\n"
        "uint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n"
        "================================================================================\n"
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
        "================================================================================\n"
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
        "================================================================================\n"
        "MSG: sensor_msgs/PointField\nuint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\n"
        "uint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\n"
        "uint8 datatype\nuint32 count\n"
    )
    with open(path, "wb") as handle:
        writer = Writer(handle)
        schema = writer.register_msgdef("sensor_msgs/msg/PointCloud2", schema_text)
        writer.write_message(
            topic="/points",
            schema=schema,
            message={
                "header": {"stamp": {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec},
                           "frame_id": "lidar"},
                "height": 1,
                "width": msg.width,
                "fields": [{"name": f.name, "offset": f.offset, "datatype": f.datatype, "count": 1}
                           for f in msg.fields],
                "is_bigendian": False,
                "point_step": msg.point_step,
                "row_step": msg.row_step,
                "data": msg.data.tobytes(),
                "is_dense": True,
            },
            log_time=stamp_ns,
            publish_time=stamp_ns,
        )  # fmt: skip
        writer.finish()
    return path
