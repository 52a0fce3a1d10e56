"""RTKLIB .pos and NMEA readers: values, time systems, and errors that name the file, line and column."""

from __future__ import annotations

import datetime as dt
import math
from functools import reduce

import pytest

from lastmile.core.gnss_messages import GnssQuality
from lastmile.recorder.gnss_text import gps_minus_utc_s, read_nmea, read_rtklib_pos
from lastmile.recorder.recorded_drive import DriveFormatError

POS_HEADER = (
    "% program   : RTKPOST ver.2.4.3 b34\n"
    "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)\n"
    "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  "
    "sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n"
)


def _unix_us(*args: int, micro: int = 0) -> int:
    moment = dt.datetime(*args, tzinfo=dt.UTC)
    return round(moment.timestamp()) * 1_000_000 + micro


def test_rtklib_gpst_times_become_utc_and_the_signed_sdne_a_covariance(tmp_path):
    path = tmp_path / "drive.pos"
    path.write_text(
        POS_HEADER
        + "2024/03/01 12:00:18.250   43.472800000  -80.540000000   330.1234   1  12   0.0040   0.0030"
        + "   0.0100  -0.0020   0.0010   0.0020   0.00   12.3\n"
        + "2024/03/01 12:00:18.500   43.472801000  -80.540001000   330.1200   2  11   0.1000   0.2000"
        + "   0.3000   0.0500   0.0000   0.0000   1.00    1.5\n"
        + "2024/03/01 12:00:18.750   43.472802000  -80.540002000   330.1200   0   0   0.0000   0.0000"
        + "   0.0000   0.0000   0.0000   0.0000   0.00    0.0\n"
    )
    fixes = read_rtklib_pos(path)
    assert len(fixes) == 2  # Q = 0 is no solution
    first, second = fixes
    assert first.utc_us == _unix_us(2024, 3, 1, 12, 0, 0, micro=250_000)  # GPST - 18 s
    assert (first.lat_deg, first.lon_deg, first.height_m) == (43.4728, -80.54, 330.1234)
    assert first.quality is GnssQuality.RTK_FIXED and second.quality is GnssQuality.RTK_FLOAT
    assert first.var_n_m2 == pytest.approx(0.004**2) and first.var_e_m2 == pytest.approx(0.003**2)
    assert first.var_en_m2 == pytest.approx(-(0.002**2))  # RTKLIB writes sign * sqrt(|cov|)
    assert second.var_en_m2 == pytest.approx(0.05**2)


def test_rtklib_week_and_seconds_times_are_read(tmp_path):
    path = tmp_path / "w.pos"
    header = POS_HEADER.replace("%  GPST                 ", "%  GPST   ")
    path.write_text(
        header + "2300 302418.000  43.4728  -80.54  330.0  5  8  1.2  1.1  2.5  0.1  0.0  0.0  0.0  0.0\n"
    )
    (fix,) = read_rtklib_pos(path)
    expected = dt.datetime(1980, 1, 6, tzinfo=dt.UTC) + dt.timedelta(weeks=2300, seconds=302418 - 18)
    assert fix.utc_us == round(expected.timestamp() * 1e6) and fix.quality is GnssQuality.SINGLE


@pytest.mark.parametrize(
    ("body", "match"),
    [
        (
            "2024/03/01 12:00:18.250 43.47 -80.54 330.1 x 12 0.004 0.003 0.01 0.0 0.0 0.0 0.0 1.0\n",
            r"drive\.pos:4, column 6 \(Q\): expected int, got 'x'",
        ),
        (
            "2024/03/01 12:00:18.250 43.47 -80.54 330.1 1 12 0.004 0.003 0.01 0.0 0.0 0.0 0.0\n",
            r"drive\.pos:4: expected 15 whitespace-separated columns, got 14",
        ),
        (
            "2024/13/01 12:00:18.250 43.47 -80.54 330.1 1 12 0.004 0.003 0.01 0.0 0.0 0.0 0.0 1.0\n",
            r"drive\.pos:4, columns 1-2 \(time\): expected 'yyyy/mm/dd hh:mm:ss.sss'",
        ),
        (
            "2024/03/01 12:00:18.250 43.47 -80.54 330.1 1 12 0.000 0.003 0.01 0.0 0.0 0.0 0.0 1.0\n",
            r"drive\.pos:4: expected positive sdn\(m\) and sde\(m\)",
        ),
    ],
)
def test_rtklib_errors_name_the_line_and_column(tmp_path, body, match):
    path = tmp_path / "drive.pos"
    path.write_text(POS_HEADER + body)
    with pytest.raises(DriveFormatError, match=match):
        read_rtklib_pos(path)


def test_rtklib_ecef_output_is_refused_with_the_fix(tmp_path):
    path = tmp_path / "ecef.pos"
    path.write_text("%  GPST   x-ecef(m)  y-ecef(m)  z-ecef(m)  Q  ns  sdx(m)  sdy(m)  sdz(m)\n")
    with pytest.raises(
        DriveFormatError, match=r"ecef\.pos:1: expected RTKLIB latitude/longitude.*out-solformat=llh"
    ):
        read_rtklib_pos(path)


def _nmea(body: str) -> str:
    checksum = reduce(lambda acc, ch: acc ^ ord(ch), body, 0)
    return f"${body}*{checksum:02X}"


def test_nmea_gga_with_rmc_date_and_gst_errors(tmp_path):
    path = tmp_path / "drive.nmea"
    lines = [
        _nmea("GNRMC,235959.80,A,4328.3680,N,08032.4000,W,5.0,90.0,010324,,,R"),
        _nmea("GNGGA,235959.80,4328.3680,N,08032.4000,W,4,12,0.8,300.0,M,-35.0,M,1.0,0000"),
        _nmea("GNGST,235959.80,0.02,0.015,0.010,30.0,0.012,0.009,0.03"),
        _nmea("GPGSV,3,1,11,01,40,083,46"),
        _nmea("GNGGA,000000.00,4328.3681,N,08032.4001,W,5,12,0.9,300.0,M,-35.0,M,1.0,0000"),
        _nmea("GNGGA,000000.20,4328.3682,N,08032.4002,W,0,00,99.9,,M,,M,,"),
    ]
    path.write_text("\n".join(lines) + "\n")
    first, second = read_nmea(path)
    assert first.utc_us == _unix_us(2024, 3, 1, 23, 59, 59, micro=800_000)
    assert second.utc_us == _unix_us(2024, 3, 2, 0, 0, 0)  # past midnight before the next RMC
    assert first.lat_deg == pytest.approx(43 + 28.368 / 60) and first.lon_deg == pytest.approx(
        -(80 + 32.4 / 60)
    )
    assert first.height_m == pytest.approx(265.0)  # MSL altitude + geoid separation
    assert (first.var_n_m2, first.var_e_m2) == pytest.approx((0.012**2, 0.009**2))  # from GST
    assert first.quality is GnssQuality.RTK_FIXED and second.quality is GnssQuality.RTK_FLOAT
    # No GST for the second epoch: the float class's accuracy times HDOP (floored at 1).
    assert second.var_n_m2 == pytest.approx(0.2**2)


def test_nmea_bad_checksum_and_missing_date_are_named(tmp_path):
    path = tmp_path / "bad.nmea"
    good = _nmea("GPGGA,120000.00,4328.3680,N,08032.4000,W,1,08,1.0,300.0,M,-35.0,M,,")
    path.write_text(good + "\n" + good[:-2] + "00\n")
    with pytest.raises(DriveFormatError, match=r"bad\.nmea:2, column \d+: expected checksum"):
        read_nmea(path)
    path.write_text(good + "\n")
    with pytest.raises(DriveFormatError, match="expected RMC sentences"):
        read_nmea(path)
    (fix,) = read_nmea(path, date=dt.date(2024, 3, 1))
    assert fix.utc_us == _unix_us(2024, 3, 1, 12, 0, 0) and fix.quality is GnssQuality.SINGLE
    assert math.sqrt(fix.var_n_m2) == pytest.approx(1.5 / 1.1774)


def test_the_leap_second_table():
    assert gps_minus_utc_s(dt.datetime(2016, 6, 1, tzinfo=dt.UTC)) == 17
    assert gps_minus_utc_s(dt.datetime(2024, 6, 1, tzinfo=dt.UTC)) == 18
