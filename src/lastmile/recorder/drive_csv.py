"""Strict readers of the documented drive CSV files (one stream per file, recognised by its header).

| header | stream |
|---|---|
| ``t_s,yaw_rate_radps,accel_x_mps2`` | IMU in the vehicle frame (accel column optional) |
| ``t_s,speed_mps`` | wheel-odometry speed, forward positive |
| ``t_s,lat_deg,lon_deg,height_m,std_east_m,std_north_m,quality`` | GNSS antenna fixes (WGS84) |

``t_s`` is UTC seconds since 1970-01-01 (decimal, up to microseconds). ``quality`` is one of
``rtk_fixed``, ``rtk_float``, ``dgnss``, ``single``. Comma separated, no quoting, no blank fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.core.gnss_messages import GnssQuality
from lastmile.recorder.recorded_drive import DriveFormatError, GeoFix, ImuSamples, WheelSamples

IMU_HEADERS = (("t_s", "yaw_rate_radps", "accel_x_mps2"), ("t_s", "yaw_rate_radps"))
WHEEL_HEADER = ("t_s", "speed_mps")
GNSS_HEADER = ("t_s", "lat_deg", "lon_deg", "height_m", "std_east_m", "std_north_m", "quality")


@dataclass(frozen=True, slots=True)
class CsvStream:
    fixes: list[GeoFix] | None = None
    imu: ImuSamples | None = None
    wheel: WheelSamples | None = None


def seconds_to_us(where: str, text: str) -> int:
    """'1700000000.123456' -> microseconds, exactly (no float rounding)."""
    whole, _, frac = text.strip().partition(".")
    if not whole.isdigit() or (frac and not frac.isdigit()) or len(frac) > 6:
        raise DriveFormatError(f"{where} (t_s): expected seconds like 1700000000.123456, got {text!r}")
    return int(whole) * 1_000_000 + int(frac.ljust(6, "0") or "0")


def read_drive_csv(path: Path) -> CsvStream:
    """Read one CSV stream; the header says which.

    Raises:
        DriveFormatError: naming the file, line and column of the first bad value.
    """
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise DriveFormatError(f"{path}: expected a file, found none") from None
    if not lines:
        raise DriveFormatError(f"{path}: expected a CSV header, got an empty file")
    header = tuple(h.strip() for h in lines[0].split(","))
    known = (*IMU_HEADERS, WHEEL_HEADER, GNSS_HEADER)
    if header not in known:
        raise DriveFormatError(
            f"{path}:1: expected one of the headers {', '.join(','.join(h) for h in known)}; got {lines[0]!r}"
        )
    rows = _rows(path, lines, header)
    if not rows:
        raise DriveFormatError(f"{path}: expected data rows after the header, found none")
    t_us = np.array([r[0] for r in rows], dtype=np.int64)
    if (np.diff(t_us) < 0).any():
        line = int(np.argmax(np.diff(t_us) < 0)) + 3
        raise DriveFormatError(f"{path}:{line}, column 1 (t_s): expected times in increasing order")
    if header == GNSS_HEADER:
        return CsvStream(fixes=[_geo(r) for r in rows])
    if header == WHEEL_HEADER:
        return CsvStream(wheel=WheelSamples(t_us, np.array([r[1] for r in rows], dtype=float)))
    accel = np.array([r[2] for r in rows], dtype=float) if len(header) == 3 else np.full(len(rows), math.nan)
    return CsvStream(imu=ImuSamples(t_us, np.array([r[1] for r in rows], dtype=float), accel))


def _rows(path: Path, lines: list[str], header: tuple[str, ...]) -> list[list]:
    rows: list[list] = []
    for number, line in enumerate(lines[1:], start=2):
        cells = line.split(",")
        if len(cells) != len(header):
            raise DriveFormatError(f"{path}:{number}: expected {len(header)} columns, got {len(cells)}")
        row: list = [seconds_to_us(f"{path}:{number}, column 1", cells[0])]
        for column, (name, cell) in enumerate(zip(header[1:], cells[1:], strict=True), start=2):
            where = f"{path}:{number}, column {column} ({name})"
            if name == "quality":
                try:
                    row.append(GnssQuality(cell.strip()))
                except ValueError:
                    names = ", ".join(q.value for q in GnssQuality)
                    raise DriveFormatError(f"{where}: expected one of {names}, got {cell!r}") from None
                continue
            try:
                value = float(cell)
            except ValueError:
                raise DriveFormatError(f"{where}: expected a number, got {cell!r}") from None
            if not math.isfinite(value):
                raise DriveFormatError(f"{where}: expected a finite number, got {cell!r}")
            if name.startswith("std_") and value <= 0:
                raise DriveFormatError(f"{where}: expected a positive standard deviation, got {cell!r}")
            if (name == "lat_deg" and abs(value) > 90) or (name == "lon_deg" and abs(value) > 180):
                raise DriveFormatError(f"{where}: expected degrees within range, got {cell!r}")
            row.append(value)
        rows.append(row)
    return rows


def _geo(row: list) -> GeoFix:
    t_us, lat, lon, h, std_e, std_n, quality = row
    return GeoFix(t_us, lat, lon, h, std_e * std_e, 0.0, std_n * std_n, quality)
