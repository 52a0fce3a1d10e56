"""Strict readers of GNSS solutions in text: RTKLIB ``.pos`` (lat/lon/height), NMEA 0183 (GGA, RMC, GST)."""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Iterator
from pathlib import Path

from lastmile.core.gnss_messages import ACCURACY_FLOOR_M, GnssQuality
from lastmile.recorder.recorded_drive import DriveFormatError, GeoFix

_UNIX = dt.datetime(1970, 1, 1, tzinfo=dt.UTC)
_GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.UTC)
# GPS time minus UTC (IERS Bulletin C): the leap seconds inserted since 1980, by the date they apply.
_LEAP_SECONDS = (
    (dt.datetime(2017, 1, 1, tzinfo=dt.UTC), 18),
    (dt.datetime(2015, 7, 1, tzinfo=dt.UTC), 17),
    (dt.datetime(2012, 7, 1, tzinfo=dt.UTC), 16),
    (dt.datetime(2009, 1, 1, tzinfo=dt.UTC), 15),
    (dt.datetime(2006, 1, 1, tzinfo=dt.UTC), 14),
    (dt.datetime(1999, 1, 1, tzinfo=dt.UTC), 13),
)
# RTKLIB's Q flag (rtklib.h SOLQ_*): 1 fix, 2 float, 3 SBAS, 4 DGPS, 5 single, 6 PPP (decimetre level
# once converged, hence the float class). 0 and 7 (none, dead reckoning) are not solutions.
_RTKLIB_Q = {
    1: GnssQuality.RTK_FIXED,
    2: GnssQuality.RTK_FLOAT,
    3: GnssQuality.DGNSS,
    4: GnssQuality.DGNSS,
    5: GnssQuality.SINGLE,
    6: GnssQuality.RTK_FLOAT,
}
# NMEA 0183 GGA quality: 1 GPS, 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float. 0 invalid, 6 dead reckoning,
# 7 manual, 8 simulator: no measurement, skipped.
_GGA_QUALITY = {
    1: GnssQuality.SINGLE,
    2: GnssQuality.DGNSS,
    3: GnssQuality.SINGLE,
    4: GnssQuality.RTK_FIXED,
    5: GnssQuality.RTK_FLOAT,
}
_GGA_NO_FIX = {0, 6, 7, 8}
_POS_REQUIRED = ("latitude(deg)", "longitude(deg)", "height(m)", "Q", "sdn(m)", "sde(m)", "sdne(m)")


def gps_minus_utc_s(utc: dt.datetime) -> int:
    """Leap seconds between GPS time and UTC at ``utc`` (GPST = UTC + this)."""
    for since, leap in _LEAP_SECONDS:
        if utc >= since:
            return leap
    raise DriveFormatError(f"GPS time before 1999: expected a drive after 1999-01-01, got {utc}")


def _us(moment: dt.datetime) -> int:
    delta = moment - _UNIX
    return (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds


def _field(where: str, name: str, text: str, kind: type[float] | type[int]) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise DriveFormatError(f"{where} ({name}): expected {kind.__name__}, got {text!r}") from None
    if not math.isfinite(value):
        raise DriveFormatError(f"{where} ({name}): expected a finite number, got {text!r}")
    return value


# --- RTKLIB .pos --------------------------------------------------------------------------------
def read_rtklib_pos(path: Path) -> list[GeoFix]:
    """Read an RTKLIB solution file in latitude/longitude/height format.

    Times in GPST are turned into UTC with the leap-second table; ``UTC`` files are taken as they are.
    The horizontal covariance is RTKLIB's ``sdn``, ``sde`` and signed ``sdne`` (sign times the square
    root of the absolute covariance).

    Raises:
        DriveFormatError: naming the file, line and column of the first thing that is not as expected.
    """
    lines = _read_lines(path)
    header: list[str] | None = None
    fixes: list[GeoFix] = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        if line.startswith("%"):
            tokens = line[1:].split()
            if tokens and tokens[0] in ("GPST", "UTC", "JST"):
                header = _pos_header(path, number, tokens)
            continue
        if header is None:
            raise DriveFormatError(
                f"{path}:{number}: expected the RTKLIB column header ('%  GPST  latitude(deg) ...') "
                f"before the first solution, got {line.strip()[:60]!r}"
            )
        fix = _pos_line(path, number, line, header)
        if fix is not None:
            fixes.append(fix)
    if header is None:
        raise DriveFormatError(
            f"{path}: expected an RTKLIB .pos file with a '%  GPST ...' header, found none"
        )
    return fixes


def _pos_header(path: Path, number: int, tokens: list[str]) -> list[str]:
    names = [tokens[0], *tokens[1:]]
    missing = [n for n in _POS_REQUIRED if n not in names]
    if missing:
        raise DriveFormatError(
            f"{path}:{number}: expected RTKLIB latitude/longitude/height output in degrees with columns "
            f"{', '.join(_POS_REQUIRED)}; missing {', '.join(missing)} (set out-solformat=llh, "
            "out-degformat=deg)"
        )
    if tokens[0] == "JST":
        raise DriveFormatError(f"{path}:{number}: expected times in GPST or UTC, got JST")
    return names


def _pos_line(path: Path, number: int, line: str, header: list[str]) -> GeoFix | None:
    tokens = line.split()
    expected = len(header) + 1  # the time takes two tokens
    if len(tokens) != expected:
        raise DriveFormatError(
            f"{path}:{number}: expected {expected} whitespace-separated columns, got {len(tokens)}"
        )
    utc = _pos_time(path, number, tokens[0], tokens[1], header[0])
    values: dict[str, str] = dict(zip(header[1:], tokens[2:], strict=True))

    def col(name: str, kind: type[float] | type[int] = float) -> float:
        column = header.index(name) + 2
        return _field(f"{path}:{number}, column {column}", name, values[name], kind)

    q = int(col("Q", int))
    if q not in _RTKLIB_Q:
        if q in (0, 7):
            return None
        raise DriveFormatError(
            f"{path}:{number}, column {header.index('Q') + 2} (Q): expected 0-7, got {values['Q']!r}"
        )
    lat, lon = col("latitude(deg)"), col("longitude(deg)")
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise DriveFormatError(f"{path}:{number}: expected latitude/longitude in degrees, got {lat}, {lon}")
    sdn, sde, sdne = col("sdn(m)"), col("sde(m)"), col("sdne(m)")
    if sdn <= 0 or sde <= 0:
        raise DriveFormatError(f"{path}:{number}: expected positive sdn(m) and sde(m), got {sdn}, {sde}")
    cov_ne = math.copysign(sdne * sdne, sdne)
    # A formal covariance can be singular in its last digit; keep it positive definite.
    limit = 0.999 * sdn * sde
    cov_ne = max(-limit, min(limit, cov_ne))
    return GeoFix(_us(utc), lat, lon, col("height(m)"), sde * sde, cov_ne, sdn * sdn, _RTKLIB_Q[q])


def _pos_time(path: Path, number: int, first: str, second: str, system: str) -> dt.datetime:
    where = f"{path}:{number}, columns 1-2 (time)"
    try:
        if "/" in first:
            moment = dt.datetime.strptime(f"{first} {second}", "%Y/%m/%d %H:%M:%S.%f").replace(tzinfo=dt.UTC)
        else:
            week, tow = int(first), float(second)
            if not (0 <= tow < 604_800 and week >= 0):
                raise ValueError
            moment = _GPS_EPOCH + dt.timedelta(weeks=week, seconds=tow)
    except ValueError:
        raise DriveFormatError(
            f"{where}: expected 'yyyy/mm/dd hh:mm:ss.sss' or 'week seconds', got {first} {second}"
        ) from None
    if system == "GPST":
        moment -= dt.timedelta(seconds=gps_minus_utc_s(moment))
    return moment


# --- NMEA 0183 ----------------------------------------------------------------------------------
def read_nmea(path: Path, date: dt.date | None = None) -> list[GeoFix]:
    """Read GGA fixes, with the date from RMC (or ``date``) and the covariance from GST when present.

    Without GST the horizontal sigma is the fix type's datasheet accuracy times HDOP. Sentences of
    other types are checked (checksum) and skipped; fixes of quality 0, 6, 7 or 8 carry no
    measurement and are skipped.

    Raises:
        DriveFormatError: naming the file, line and field of the first bad sentence, or no date.
    """
    gga: list[tuple[int, float, list[str], str]] = []  # (line, seconds of day, fields, where)
    gst: dict[str, tuple[float, float]] = {}
    dates: list[tuple[int, dt.date]] = []
    for number, kind, fields in _sentences(path):
        where = f"{path}:{number}"
        if kind == "GGA":
            if len(fields) < 14:
                raise DriveFormatError(f"{where}: expected 14 GGA fields, got {len(fields)}")
            gga.append((number, _time_of_day(where, fields[0]), fields, where))
        elif kind == "RMC" and len(fields) >= 9 and fields[8]:
            dates.append((number, _rmc_date(where, fields[8])))
        elif kind == "GST" and len(fields) >= 7 and fields[5] and fields[6]:
            lat_err = _field(f"{where}, field 6", "latitude error", fields[5], float)
            lon_err = _field(f"{where}, field 7", "longitude error", fields[6], float)
            gst[fields[0]] = (lat_err, lon_err)
    if not gga:
        raise DriveFormatError(f"{path}: expected NMEA GGA sentences, found none")
    if not dates and date is None:
        raise DriveFormatError(f"{path}: expected RMC sentences (for the date) or a date, found neither")
    fixes: list[GeoFix] = []
    day = dates[0][1] if dates else date
    assert day is not None
    previous = -1.0
    date_index = 0
    for number, seconds, fields, where in gga:
        new_date = False
        while date_index < len(dates) and dates[date_index][0] <= number:
            day, new_date = dates[date_index][1], True
            date_index += 1
        if previous >= 0 and seconds < previous - 43_200 and not new_date:
            day = day + dt.timedelta(days=1)  # midnight passed before the next RMC date
        previous = seconds
        fix = _gga_fix(where, fields, day, seconds, gst.get(fields[0]))
        if fix is not None:
            fixes.append(fix)
    return fixes


def _sentences(path: Path) -> Iterator[tuple[int, str, list[str]]]:
    for number, raw in enumerate(_read_lines(path), start=1):
        line = raw.strip()
        if not line:
            continue
        if not line.startswith("$") or "*" not in line:
            raise DriveFormatError(f"{path}:{number}: expected an NMEA sentence '$...*hh', got {line[:60]!r}")
        body, _, checksum = line[1:].rpartition("*")
        computed = 0
        for char in body:
            computed ^= ord(char)
        if checksum.upper() != f"{computed:02X}":
            raise DriveFormatError(
                f"{path}:{number}, column {len(body) + 3}: expected checksum {computed:02X}, got {checksum!r}"
            )
        fields = body.split(",")
        if len(fields[0]) != 5:
            raise DriveFormatError(
                f"{path}:{number}: expected a talker and type like GPGGA, got {fields[0]!r}"
            )
        yield number, fields[0][2:], fields[1:]


def _time_of_day(where: str, text: str) -> float:
    try:
        h, m, s = int(text[0:2]), int(text[2:4]), float(text[4:])
        if not (0 <= h < 24 and 0 <= m < 60 and 0 <= s < 61):
            raise ValueError
    except ValueError:
        raise DriveFormatError(f"{where}, field 1 (time): expected hhmmss.ss, got {text!r}") from None
    return h * 3600 + m * 60 + s


def _rmc_date(where: str, text: str) -> dt.date:
    try:
        return dt.datetime.strptime(text, "%d%m%y").date()
    except ValueError:
        raise DriveFormatError(f"{where}, field 9 (date): expected ddmmyy, got {text!r}") from None


def _angle(where: str, field_no: int, text: str, hemi: str, degrees_digits: int, positive: str) -> float:
    name = "latitude" if degrees_digits == 2 else "longitude"
    try:
        value = int(text[:degrees_digits]) + float(text[degrees_digits:]) / 60.0
    except ValueError:
        raise DriveFormatError(
            f"{where}, field {field_no} ({name}): expected {'d' * degrees_digits}mm.mmmm, got {text!r}"
        ) from None
    if hemi not in ("NS" if degrees_digits == 2 else "EW"):
        raise DriveFormatError(f"{where}, field {field_no + 1}: expected a hemisphere letter, got {hemi!r}")
    return value if hemi == positive else -value


def _gga_fix(
    where: str, fields: list[str], day: dt.date, seconds: float, gst: tuple[float, float] | None
) -> GeoFix | None:
    quality_no = int(_field(f"{where}, field 6", "quality", fields[5], int))
    if quality_no in _GGA_NO_FIX:
        return None
    if quality_no not in _GGA_QUALITY:
        raise DriveFormatError(f"{where}, field 6 (quality): expected 0-8, got {fields[5]!r}")
    quality = _GGA_QUALITY[quality_no]
    lat = _angle(where, 2, fields[1], fields[2], 2, "N")
    lon = _angle(where, 4, fields[3], fields[4], 3, "E")
    altitude = _field(f"{where}, field 9", "altitude", fields[8], float)
    separation = _field(f"{where}, field 11", "geoid separation", fields[10], float) if fields[10] else 0.0
    if gst is not None:
        var_n, var_e = gst[0] ** 2, gst[1] ** 2
    else:
        hdop = _field(f"{where}, field 8", "HDOP", fields[7], float)
        var_n = var_e = (ACCURACY_FLOOR_M[quality] * max(hdop, 1.0)) ** 2
    if var_n <= 0 or var_e <= 0:
        raise DriveFormatError(f"{where}: expected positive position errors (GST), got {var_n}, {var_e}")
    moment = dt.datetime.combine(day, dt.time(), tzinfo=dt.UTC) + dt.timedelta(seconds=seconds)
    return GeoFix(_us(moment), lat, lon, altitude + separation, var_e, 0.0, var_n, quality)


def _read_lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="ascii").splitlines()
    except FileNotFoundError:
        raise DriveFormatError(f"{path}: expected a file, found none") from None
    except UnicodeDecodeError as exc:
        raise DriveFormatError(
            f"{path}: expected ASCII text, got byte {exc.object[exc.start]:#x} at offset {exc.start}"
        ) from None
