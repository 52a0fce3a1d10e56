"""GEM-style recorded waypoint files: one waypoint a line, latitude, longitude and speed.

The Polaris GEM shuttle's waypoint follower reads "a series of triplets listing the latitude,
longitude and speed of each waypoint", recorded by driving the route. Lines are comma or white-space
separated; a first line that is not numbers is a header; ``#`` starts a comment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import FloatArray


@dataclass(frozen=True, slots=True, kw_only=True)
class RecordedWaypoints:
    """A recorded drive.

    Attributes:
        lat_deg, lon_deg: (N,) degrees.
        speed_mps: (N,) the recorded target speed at each waypoint (m/s, as the file gives it).
    """

    lat_deg: FloatArray
    lon_deg: FloatArray
    speed_mps: FloatArray


def read_waypoints(path: str | Path) -> RecordedWaypoints:
    """Read a waypoint file strictly.

    Raises:
        ConfigError: a missing file, a line without exactly three numbers (naming the line and what
            it held), a latitude/longitude out of range, a negative speed, or fewer than two waypoints.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(
            f"waypoints {str(p)!r}: expected a file of latitude, longitude, speed lines, got none"
        )
    rows: list[tuple[float, float, float]] = []
    for number, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        fields = text.replace(",", " ").split()
        try:
            values = [float(f) for f in fields]
        except ValueError:
            if not rows and number == _first_content_line(p):
                continue  # a header such as "lat,lon,speed"
            raise ConfigError(
                f"waypoints {p.name} line {number}: expected three numbers (latitude, longitude, speed), "
                f"got {text!r}"
            ) from None
        if len(values) != 3:
            raise ConfigError(
                f"waypoints {p.name} line {number}: expected three numbers (latitude, longitude, speed), "
                f"got {len(values)}: {text!r}"
            )
        lat, lon, speed = values
        if not (abs(lat) <= 90 and abs(lon) <= 180 and math.isfinite(speed) and speed >= 0):
            raise ConfigError(
                f"waypoints {p.name} line {number}: expected latitude within +-90, longitude within +-180 "
                f"and a speed >= 0, got {lat}, {lon}, {speed}"
            )
        rows.append((lat, lon, speed))
    if len(rows) < 2:
        raise ConfigError(f"waypoints {p.name}: expected at least two waypoints, got {len(rows)}")
    arr = np.array(rows, dtype=float)
    for col in range(3):
        arr[:, col].setflags(write=False)
    return RecordedWaypoints(lat_deg=arr[:, 0], lon_deg=arr[:, 1], speed_mps=arr[:, 2])


def _first_content_line(p: Path) -> int:
    for number, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
        if line.split("#", 1)[0].strip():
            return number
    return 0
