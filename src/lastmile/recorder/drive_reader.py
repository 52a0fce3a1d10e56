"""Read a recorded drive from its files, whatever mix of formats: one GNSS stream, IMU and/or wheel speed."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

from lastmile.recorder.drive_csv import read_drive_csv
from lastmile.recorder.drive_rosbag import BagTopics, read_rosbag
from lastmile.recorder.gnss_text import read_nmea, read_rtklib_pos
from lastmile.recorder.recorded_drive import (
    DriveFormatError,
    GeoFix,
    ImuSamples,
    RecordedDrive,
    WheelSamples,
    assemble_drive,
)

BAG_SUFFIXES = (".bag", ".mcap", ".db3")
NMEA_SUFFIXES = (".nmea", ".nma", ".gga", ".ubx.nmea")


def read_drive(
    paths: list[Path],
    topics: BagTopics | None = None,
    imu_forward_axis: str = "x",
    nmea_date: dt.date | None = None,
) -> RecordedDrive:
    """Read every file (RTKLIB ``.pos``, NMEA, documented CSV, ROS 1 bag, rosbag2) into one drive.

    Raises:
        DriveFormatError: an unknown format, two sources of the same stream, or a reader's error.
    """
    fixes: list[tuple[str, list[GeoFix]]] = []
    imus: list[tuple[str, ImuSamples]] = []
    wheels: list[tuple[str, WheelSamples]] = []
    for path in paths:
        kind = _kind(path)
        if kind == "bag":
            streams = read_rosbag(path, topics or BagTopics(), imu_forward_axis)
            name = f"{path} ({', '.join(streams.topics)})"
            if streams.fixes:
                fixes.append((name, streams.fixes))
            if streams.imu is not None:
                imus.append((name, streams.imu))
            if streams.wheel is not None:
                wheels.append((name, streams.wheel))
        elif kind == "pos":
            fixes.append((str(path), read_rtklib_pos(path)))
        elif kind == "nmea":
            fixes.append((str(path), read_nmea(path, nmea_date)))
        else:
            csv = read_drive_csv(path)
            if csv.fixes is not None:
                fixes.append((str(path), csv.fixes))
            if csv.imu is not None:
                imus.append((str(path), csv.imu))
            if csv.wheel is not None:
                wheels.append((str(path), csv.wheel))
    for what, found in (("GNSS", fixes), ("IMU", imus), ("wheel-speed", wheels)):
        if len(found) > 1:
            raise DriveFormatError(
                f"expected one {what} stream, got {len(found)}: {', '.join(name for name, _ in found)}"
            )
    sources = tuple(dict.fromkeys(name for group in (fixes, imus, wheels) for name, _ in group))
    return assemble_drive(
        fixes[0][1] if fixes else [],
        imus[0][1] if imus else None,
        wheels[0][1] if wheels else None,
        sources or tuple(str(p) for p in paths),
    )


def _kind(path: Path) -> str:
    name = path.name.lower()
    if path.is_dir() or name.endswith(BAG_SUFFIXES):
        return "bag"
    if name.endswith(".pos"):
        return "pos"
    if name.endswith(NMEA_SUFFIXES):
        return "nmea"
    if name.endswith(".csv"):
        return "csv"
    raise DriveFormatError(
        f"{path}: expected a .pos (RTKLIB), .nmea, .csv, .bag, .mcap or .db3 file or a rosbag2 directory, "
        f"got suffix {path.suffix!r}"
    )
