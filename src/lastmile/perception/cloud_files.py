"""Point clouds from files: KITTI ``.bin``, PCD, and ``sensor_msgs/PointCloud2`` in rosbag2 or MCAP files.

Every reader is strict: a file that is not what its name says, a missing coordinate, a non-finite
value or an unknown point layout raises :class:`MessageError` naming the file (and the field or
topic). What a file does not carry (ring, per-point time, intensity) is left ``None`` for
:func:`sweep_from_cloud` to derive from the sensor's model, which reports what it derived.

Per-point fields recognised (the names the common drivers write):

- intensity: ``intensity`` (KITTI's ``.bin`` reflectance, 0..1, is its 4th column, read as 0..255);
- ring: ``ring`` (Velodyne, Ouster and Hesai drivers);
- time: ``t_offset_us`` (this project, us after the stamp), ``time`` (velodyne_pointcloud, float
  seconds after the message stamp), ``t`` (Ouster, integer ns after the stamp), ``timestamp``
  (Hesai, absolute float seconds: the earliest becomes the stamp).
"""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.errors import MessageError
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.perception.lidar_model import (
    LidarSensorConfig,
    RingSource,
    TimeSource,
    ring_from_elevation,
    ring_from_scan_order,
    time_from_azimuth,
)

POINTCLOUD2_TYPE = "sensor_msgs/msg/PointCloud2"
# sensor_msgs/PointField datatypes.
_POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


class CloudFormat(enum.Enum):
    """File kinds the readers accept, chosen by the path."""

    KITTI_BIN = "kitti_bin"  # *.bin: float32 x y z reflectance
    PCD = "pcd"  # *.pcd
    ROSBAG2 = "rosbag2"  # a rosbag2 directory (metadata.yaml; sqlite3 or mcap storage)
    MCAP = "mcap"  # a bare *.mcap file with ROS 2 (cdr) messages


@dataclass(frozen=True, slots=True, kw_only=True)
class RawCloud:
    """One sweep as a file holds it, in the sensor frame.

    Attributes:
        name: the file (and message index) it came from, for errors and outputs.
        stamp_us: capture time of the sweep (int us; 0 when the file has none).
        xyz_m: (N, 3) float32 finite points.
        intensity: (N,) float32 as stored, or None.
        ring: (N,) int64, or None.
        t_offset_us: (N,) float64 firing time after ``stamp_us``, or None.
    """

    name: str
    stamp_us: int
    xyz_m: np.ndarray
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None
    t_offset_us: np.ndarray | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class SweepProvenance:
    """What of a sweep came from the file and what from the model (reported with the outputs)."""

    ring: str
    time: str
    intensity: str


def cloud_format(path: Path) -> CloudFormat:
    """The reader a path needs, by its name (a directory is a rosbag2)."""
    if path.is_dir():
        return CloudFormat.ROSBAG2
    suffix = path.suffix.lower()
    kinds = {".bin": CloudFormat.KITTI_BIN, ".pcd": CloudFormat.PCD, ".mcap": CloudFormat.MCAP}
    if suffix not in kinds:
        raise MessageError(
            f"{path}: expected a .bin (KITTI), .pcd or .mcap file or a rosbag2 directory, got {suffix!r}"
        )
    return kinds[suffix]


def read_clouds(path: Path, topic: str | None = None) -> Iterator[RawCloud]:
    """Every sweep in a file, in order (one for ``.bin`` and ``.pcd``, one per message for bags)."""
    if not path.exists():
        raise MessageError(f"{path}: expected a point-cloud file, got no such file or directory")
    fmt = cloud_format(path)
    if fmt is CloudFormat.KITTI_BIN:
        yield read_kitti_bin(path)
    elif fmt is CloudFormat.PCD:
        yield read_pcd(path)
    elif fmt is CloudFormat.ROSBAG2:
        yield from read_rosbag2(path, topic)
    else:
        yield from read_mcap(path, topic)


def read_kitti_bin(path: Path) -> RawCloud:
    """A KITTI velodyne ``.bin``: float32 rows ``x y z reflectance`` (reflectance 0..1)."""
    raw = path.read_bytes()
    if len(raw) == 0 or len(raw) % 16:
        raise MessageError(
            f"{path}: expected float32 rows of x y z reflectance (a multiple of 16 bytes), "
            f"got {len(raw)} bytes"
        )
    a = np.frombuffer(raw, dtype="<f4").reshape(-1, 4)
    _check_finite(a, path.name, ("x", "y", "z", "reflectance"))
    if a[:, 3].min() < 0 or a[:, 3].max() > 1:
        raise MessageError(
            f"{path}: column 4 (reflectance): expected 0..1, got {a[:, 3].min():.3g}..{a[:, 3].max():.3g}"
        )
    # On the pipeline's 0..255 intensity scale, as drivers deliver it.
    return RawCloud(name=path.name, stamp_us=0, xyz_m=a[:, :3].copy(), intensity=a[:, 3] * np.float32(255.0))


def read_pcd(path: Path) -> RawCloud:
    """A PCD file (ASCII, binary or binary_compressed) with at least x, y, z fields."""
    from pypcd4 import PointCloud

    try:
        pc = PointCloud.from_path(path)
    except Exception as exc:  # pypcd4 raises bare ValueErrors and struct errors on malformed headers
        raise MessageError(f"{path}: expected a PCD file, got one pypcd4 cannot read ({exc})") from None
    return _from_structured(pc.pc_data, path.name, stamp_us=0, drop_nan=True)


def read_rosbag2(path: Path, topic: str | None) -> Iterator[RawCloud]:
    """``sensor_msgs/msg/PointCloud2`` messages of one topic of a rosbag2 directory, in log order."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.LATEST)
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises its own ReaderError on a malformed bag
        raise MessageError(
            f"{path}: expected a rosbag2 directory, got one rosbags cannot open ({exc})"
        ) from None
    try:
        clouds = {c.topic: c for c in reader.connections if c.msgtype == POINTCLOUD2_TYPE}
        chosen = _choose_topic(path, topic, sorted(clouds), sorted({c.topic for c in reader.connections}))
        conns = [c for c in reader.connections if c.topic == chosen]
        for k, (conn, _, data) in enumerate(reader.messages(connections=conns)):
            msg = store.deserialize_cdr(data, conn.msgtype)
            yield pointcloud2_to_cloud(msg, f"{path.name}:{chosen}[{k}]")
    finally:
        reader.close()


def read_mcap(path: Path, topic: str | None) -> Iterator[RawCloud]:
    """``sensor_msgs/msg/PointCloud2`` messages of one topic of a bare MCAP file (ROS 2 cdr encoding)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as handle:
        try:
            reader = make_reader(handle, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
        except Exception as exc:  # the mcap library raises several kinds on a bad file
            raise MessageError(f"{path}: expected an MCAP file, got one mcap cannot read ({exc})") from None
        if summary is None:
            raise MessageError(f"{path}: expected an MCAP file with a summary, got none")
        schema_of = {c.topic: summary.schemas.get(c.schema_id) for c in summary.channels.values()}
        clouds = sorted(t for t, s in schema_of.items() if s is not None and s.name == POINTCLOUD2_TYPE)
        chosen = _choose_topic(path, topic, clouds, sorted(schema_of))
        for k, (_, _, _, msg) in enumerate(reader.iter_decoded_messages(topics=[chosen])):
            yield pointcloud2_to_cloud(msg, f"{path.name}:{chosen}[{k}]")


def _choose_topic(path: Path, topic: str | None, clouds: list[str], topics: list[str]) -> str:
    if topic is not None:
        if topic not in clouds:
            raise MessageError(
                f"{path}: expected topic {topic!r} of type {POINTCLOUD2_TYPE}, got topics {topics}"
            )
        return topic
    if len(clouds) != 1:
        raise MessageError(
            f"{path}: expected exactly one {POINTCLOUD2_TYPE} topic (or a topic in the configuration), "
            f"got {clouds or 'none'} among {topics}"
        )
    return clouds[0]


def pointcloud2_to_cloud(msg: Any, where: str) -> RawCloud:
    """A decoded ``sensor_msgs/msg/PointCloud2`` (rosbags or mcap-ros2 object) as a :class:`RawCloud`.

    Organised clouds mark missing returns with NaN coordinates; those points are dropped.
    """
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if int(f.datatype) not in _POINTFIELD_DTYPES:
            raise MessageError(
                f"{where}: field {f.name!r}: expected PointField datatype 1..8, got {f.datatype}"
            )
        if int(f.count) != 1:
            continue  # array fields (e.g. padding, descriptors) are not per-point scalars we read
        names.append(str(f.name))
        formats.append((">" if msg.is_bigendian else "<") + _POINTFIELD_DTYPES[int(f.datatype)])
        offsets.append(int(f.offset))
    step, n = int(msg.point_step), int(msg.width) * int(msg.height)
    if any(o + np.dtype(fm).itemsize > step for o, fm in zip(offsets, formats, strict=True)):
        raise MessageError(f"{where}: expected fields within point_step {step}, got offsets {offsets}")
    data = np.asarray(msg.data, dtype=np.uint8).tobytes() if not isinstance(msg.data, bytes) else msg.data
    row_step = int(msg.row_step)
    if row_step < int(msg.width) * step or len(data) < row_step * int(msg.height):
        raise MessageError(
            f"{where}: expected {msg.height} rows of {row_step} bytes ({n} points of {step}), "
            f"got {len(data)} bytes"
        )
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    rows = [
        np.frombuffer(data, dtype=dtype, count=int(msg.width), offset=r * row_step)
        for r in range(int(msg.height))
    ]
    points = np.concatenate(rows) if rows else np.zeros(0, dtype=dtype)
    stamp_us = int(msg.header.stamp.sec) * 1_000_000 + int(msg.header.stamp.nanosec) // 1000
    return _from_structured(points, where, stamp_us=stamp_us, drop_nan=True)


def _from_structured(points: np.ndarray, where: str, stamp_us: int, drop_nan: bool) -> RawCloud:
    names = points.dtype.names or ()
    missing = [c for c in ("x", "y", "z") if c not in names]
    if missing:
        raise MessageError(f"{where}: expected fields x, y, z, got {list(names)} (missing {missing})")
    xyz = np.stack([points[c].astype(np.float32) for c in ("x", "y", "z")], axis=1)
    keep = np.isfinite(xyz).all(axis=1)
    if drop_nan and not keep.all():
        points, xyz = points[keep], xyz[keep]  # NaN marks "no return" in organised clouds
    if len(xyz) == 0:
        raise MessageError(f"{where}: expected at least one finite point, got none")
    intensity = points["intensity"].astype(np.float32) if "intensity" in names else None
    if intensity is not None:
        _check_finite(intensity[:, None], where, ("intensity",))
    ring = None
    if "ring" in names:
        if not np.issubdtype(points.dtype["ring"], np.integer):
            raise MessageError(f"{where}: field 'ring': expected an integer type, got {points.dtype['ring']}")
        ring = points["ring"].astype(np.int64)
        if ring.min() < 0:
            raise MessageError(f"{where}: field 'ring': expected >= 0, got {int(ring.min())}")
    t_offset, stamp_us = _point_times(points, where, stamp_us)
    return RawCloud(
        name=where, stamp_us=stamp_us, xyz_m=xyz, intensity=intensity, ring=ring, t_offset_us=t_offset
    )


def _point_times(points: np.ndarray, where: str, stamp_us: int) -> tuple[np.ndarray | None, int]:
    names = points.dtype.names or ()
    if "t_offset_us" in names:
        t = points["t_offset_us"].astype(np.float64)
    elif "time" in names:
        t = points["time"].astype(np.float64) * 1e6  # velodyne_pointcloud: seconds after the stamp
    elif "t" in names:
        if not np.issubdtype(points.dtype["t"], np.integer):
            raise MessageError(f"{where}: field 't': expected integer ns (Ouster), got {points.dtype['t']}")
        t = points["t"].astype(np.float64) * 1e-3
    elif "timestamp" in names:
        absolute = points["timestamp"].astype(np.float64)  # Hesai: absolute seconds
        _check_finite(absolute[:, None], where, ("timestamp",))
        first = float(absolute.min())
        return (absolute - first) * 1e6, round(first * 1e6)
    else:
        return None, stamp_us
    _check_finite(t[:, None], where, ("per-point time",))
    return t, stamp_us


def _check_finite(a: np.ndarray, where: str, columns: tuple[str, ...]) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        row, col = (int(v) for v in np.argwhere(bad)[0])
        raise MessageError(
            f"{where}: {columns[col]}: expected finite values, got {a[row, col]} at point {row}"
        )


def sweep_from_cloud(cloud: RawCloud, sensor: LidarSensorConfig) -> tuple[LidarSweep, SweepProvenance]:
    """The pipeline's :class:`LidarSweep` from a file's cloud, deriving what the file lacks.

    Raises:
        MessageError: the configuration asks for a ring or time field the file does not have, or
            the points do not fit the model's beams (:func:`ring_from_elevation`).
    """
    n = len(cloud.xyz_m)
    if sensor.ring is RingSource.FIELD and cloud.ring is None:
        raise MessageError(f"{cloud.name}: expected a 'ring' field (sensor.ring = 'field'), got none")
    if sensor.ring is RingSource.SCAN_ORDER:
        ring, ring_from = ring_from_scan_order(cloud.xyz_m, sensor.model, cloud.name), "scan order"
    elif cloud.ring is not None and sensor.ring is not RingSource.ELEVATION:
        ring, ring_from = cloud.ring, "file"
    else:
        ring, ring_from = ring_from_elevation(cloud.xyz_m, sensor.model, cloud.name), "elevation"
    if sensor.time is TimeSource.FIELD and cloud.t_offset_us is None:
        raise MessageError(f"{cloud.name}: expected a per-point time field (sensor.time = 'field'), got none")
    if sensor.time is TimeSource.SWEEP:
        t, time_from = np.zeros(n), "sweep stamp"
    elif cloud.t_offset_us is not None and sensor.time is not TimeSource.AZIMUTH:
        t, time_from = cloud.t_offset_us, "file"
    else:
        t, time_from = time_from_azimuth(cloud.xyz_m, sensor.model), "azimuth"
    if cloud.intensity is None:
        intensity, intensity_from = np.zeros(n), "absent (0)"
    else:
        intensity, intensity_from = cloud.intensity.astype(np.float64) * sensor.intensity_scale, "file"
    pts = np.empty((n, 6), dtype=np.float32)
    pts[:, :3] = cloud.xyz_m
    pts[:, 3] = intensity
    pts[:, 4] = ring
    pts[:, 5] = t
    sweep = LidarSweep(stamp=Stamp(cloud.stamp_us), sensor_id=sensor.sensor_id, points=pts)
    return sweep, SweepProvenance(ring=ring_from, time=time_from, intensity=intensity_from)
