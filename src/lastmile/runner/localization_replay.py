"""Replay a recorded drive through a localization mode, with GNSS dropped in chosen windows, and score it.

The reference is the drive's own GNSS: every fix, those dropped in an outage included, is compared
with the estimate of the antenna (base pose plus lever arm) at the fix's stamp. What is printed:
absolute trajectory error (evo's ``evo_ape`` statistics, no alignment: both are in the same frame),
p95 error over the run, lateral and longitudinal error at the end of each outage, normalised
estimation error squared (NEES) against the 95 % chi-square bound, the share of fixes the filter
rejected outside outages, and the time to accept GNSS again after each outage.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import NamedTuple

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.gnss_messages import ACCURACY_FLOOR_M, GnssFix, white_covariance_m2
from lastmile.core.stamp import Stamp
from lastmile.evaluation.trajectory_metrics import (
    CHI2_2DOF_95,
    ApeStatistics,
    along_cross_track_m,
    ape_statistics,
    nees_2d,
    position_errors_m,
)
from lastmile.localization.ekf import PoseEkf, PoseEkfConfig
from lastmile.recorder.recorded_drive import RecordedDrive


class LocalizationMode(Enum):
    """Modes ``lastmile eval localization --mode`` runs on a recorded drive."""

    EKF = "ekf"
    """The pose EKF on IMU, wheel speed and every GNSS fix outside the outages."""
    DEAD_RECKONING = "dead_reckoning"
    """The same filter given GNSS only until it is initialised (position and heading), then none."""


@dataclass(frozen=True, slots=True)
class Outage:
    """GNSS dropped from ``start_s`` (seconds after the drive's first sample) for ``duration_s``."""

    start_s: float
    duration_s: float

    @staticmethod
    def parse(text: str) -> Outage:
        start, sep, duration = text.partition(":")
        try:
            outage = Outage(float(start), float(duration))
        except ValueError:
            outage = None
        if not sep or outage is None or not (outage.start_s >= 0 and outage.duration_s > 0):
            raise ConfigError(f"--outage: expected START:DURATION in seconds (e.g. 120:30), got {text!r}")
        if not (math.isfinite(outage.start_s) and math.isfinite(outage.duration_s)):
            raise ConfigError(f"--outage: expected finite seconds, got {text!r}")
        return outage

    def contains(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.start_s + self.duration_s

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s


@dataclass(frozen=True, slots=True, kw_only=True)
class OutageResult:
    """Scores of one outage. Errors are of the last reference fix inside it (estimate - reference)."""

    outage: Outage
    end_error_m: float
    end_longitudinal_m: float
    end_lateral_m: float
    end_sigma_m: float
    max_error_m: float
    nees_within_bound: float
    reacquired_after_s: float | None


@dataclass(frozen=True, slots=True, kw_only=True)
class ReplayResult:
    """A replay's per-fix trace and its scores.

    Attributes:
        t_s: (N,) stamps of the reference fixes with an estimate (initialised, heading known), s.
        estimate_xy, reference_xy: (N, 2) antenna positions, m.
        estimate_yaw_rad: (N,).
        nees: (N,) against the estimate's covariance plus the reference fix's own.
        in_outage: (N,) bool.
        valid: (N,) bool: the estimate's own validity flag.
    """

    mode: LocalizationMode
    t_s: np.ndarray
    estimate_xy: np.ndarray
    reference_xy: np.ndarray
    estimate_yaw_rad: np.ndarray
    nees: np.ndarray
    in_outage: np.ndarray
    valid: np.ndarray
    ape: ApeStatistics
    p95_error_m: float
    nees_within_bound: float
    offered_fixes: int
    rejected_fixes: int
    resets: int
    outages: tuple[OutageResult, ...]
    used_accelerometer: bool
    used_wheel_speed: bool
    compute_us_per_input: float
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def rejected_share(self) -> float:
        return self.rejected_fixes / self.offered_fixes if self.offered_fixes else 0.0


def replay_drive(
    drive: RecordedDrive,
    outages: tuple[Outage, ...] = (),
    mode: LocalizationMode = LocalizationMode.EKF,
    config: PoseEkfConfig | None = None,
    use_accelerometer: bool | None = None,
) -> ReplayResult:
    """Run ``mode`` over the drive and score it against the drive's GNSS.

    Args:
        use_accelerometer: None: only when there is no wheel speed (an IMU's forward axis in a bag is a
            guess; the wheel speed is not).

    Raises:
        ConfigError: the drive lacks what the mode needs (a yaw rate; a speed or an accelerometer).
    """
    config = config or PoseEkfConfig(zero_slip_offset_m=0.0)
    has_wheel = drive.wheel_us.size > 0
    if drive.imu_us.size == 0:
        raise ConfigError(f"{', '.join(drive.sources)}: expected an IMU yaw-rate stream, found none")
    accel = (not has_wheel) if use_accelerometer is None else use_accelerometer
    if accel and not drive.has_accelerometer:
        raise ConfigError(
            f"{', '.join(drive.sources)}: expected wheel speed or a longitudinal acceleration, found neither"
        )
    ekf = PoseEkf(config)
    events = _merged_events(drive)
    rows: list[_FixRow] = []
    used_at: list[tuple[float, bool]] = []
    offered = 0
    heading_known = False
    started = time.perf_counter()
    for stamp, kind, index in events:
        if kind == 0:
            a = float(drive.imu_accel_x_mps2[index]) if accel else None
            ekf.imu(Stamp(stamp), float(drive.imu_yaw_rate_radps[index]), a)
        elif kind == 1:
            ekf.wheel_speed(Stamp(stamp), float(drive.wheel_speed_mps[index]))
        else:
            fix = drive.fixes[index]
            t_s = stamp / 1e6
            dead_reckoning = mode is LocalizationMode.DEAD_RECKONING and heading_known
            dropped = dead_reckoning or any(o.contains(t_s) for o in outages)
            if not dropped:
                offered += 1
                used_at.append((t_s, ekf.update_position(fix)))
            rows.append(_row(ekf, config, fix, t_s, any(o.contains(t_s) for o in outages)))
            heading_known = rows[-1].heading_known
    elapsed = time.perf_counter() - started
    return _score(
        mode, rows, used_at, outages, ekf, offered, accel, has_wheel, elapsed / max(len(events), 1) * 1e6
    )


def _merged_events(drive: RecordedDrive) -> list[tuple[int, int, int]]:
    """(stamp, kind, index) in time order; at equal stamps IMU, then wheel, then GNSS."""
    stamps = np.concatenate(
        [drive.imu_us, drive.wheel_us, np.array([f.stamp for f in drive.fixes], dtype=np.int64)]
    )
    kinds = np.concatenate(
        [np.zeros(drive.imu_us.size, int), np.ones(drive.wheel_us.size, int), np.full(len(drive.fixes), 2)]
    )
    index = np.concatenate(
        [np.arange(drive.imu_us.size), np.arange(drive.wheel_us.size), np.arange(len(drive.fixes))]
    )
    order = np.lexsort((kinds, stamps))
    return list(zip(stamps[order].tolist(), kinds[order].tolist(), index[order].tolist(), strict=True))


class _FixRow(NamedTuple):
    t_s: float
    in_outage: bool
    yaw_rad: float
    heading_known: bool
    antenna_xy: np.ndarray  # (2,) the estimate of the antenna, m
    reference_xy: np.ndarray  # (2,) the fix, m
    covariance: np.ndarray  # (2, 2) estimate's plus reference's, m^2
    valid: bool


def _row(ekf: PoseEkf, config: PoseEkfConfig, fix: GnssFix, t_s: float, in_outage: bool) -> _FixRow:
    """The estimate of the antenna at the fix's stamp, against the fix (white and correlated error)."""
    post = ekf.posterior(fix.stamp)
    lf, ll = config.antenna_lever_arm_m
    x, y, yaw = post.state[:3]
    c, s = math.cos(yaw), math.sin(yaw)
    antenna = np.array([x + c * lf - s * ll, y + s * lf + c * ll])
    jac = np.array([[1.0, 0.0, -s * lf - c * ll], [0.0, 1.0, c * lf - s * ll]])
    p_antenna = jac @ post.covariance[:3, :3] @ jac.T
    xx, xy, yy = white_covariance_m2(fix)
    r_ref = np.array([[xx, xy], [xy, yy]]) + ACCURACY_FLOOR_M[fix.quality] ** 2 * np.eye(2)
    return _FixRow(
        t_s,
        in_outage,
        float(yaw),
        post.initialised and post.yaw_known,
        antenna,
        np.array([fix.x_m, fix.y_m]),
        p_antenna + r_ref,
        ekf.estimate(fix.stamp).valid,
    )


def _score(
    mode: LocalizationMode,
    all_rows: list[_FixRow],
    used_at: list[tuple[float, bool]],
    outages: tuple[Outage, ...],
    ekf: PoseEkf,
    offered: int,
    accel: bool,
    has_wheel: bool,
    us_per_input: float,
) -> ReplayResult:
    rows = [r for r in all_rows if r.heading_known]
    if not rows:
        raise ConfigError("the filter never initialised (position and heading): did the drive move 5 m?")
    t = np.array([r.t_s for r in rows])
    inside = np.array([r.in_outage for r in rows])
    yaw = np.array([r.yaw_rad for r in rows])
    est = np.array([r.antenna_xy for r in rows])
    ref = np.array([r.reference_xy for r in rows])
    cov = np.array([r.covariance for r in rows])
    valid = np.array([r.valid for r in rows])
    err = position_errors_m(est, ref)
    nees = nees_2d(est - ref, cov)
    results = []
    for outage in outages:
        sel = np.flatnonzero((t >= outage.start_s) & (t < outage.end_s))
        if sel.size == 0:
            raise ConfigError(
                f"--outage {outage.start_s:g}:{outage.duration_s:g}: expected GNSS fixes inside it "
                f"(the drive has estimates from {t[0]:.1f} to {t[-1]:.1f} s)"
            )
        last = sel[-1]
        lon, lat = along_cross_track_m((est - ref)[last : last + 1], yaw[last : last + 1])
        after = [ts for ts, used in used_at if ts >= outage.end_s and used]
        results.append(
            OutageResult(
                outage=outage,
                end_error_m=float(err[last]),
                end_longitudinal_m=float(lon[0]),
                end_lateral_m=float(lat[0]),
                end_sigma_m=float(math.sqrt(max(np.linalg.eigvalsh(cov[last])))),
                max_error_m=float(err[sel].max()),
                nees_within_bound=float(np.mean(nees[sel] <= CHI2_2DOF_95)),
                reacquired_after_s=(after[0] - outage.end_s) if after else None,
            )
        )
    return ReplayResult(
        mode=mode,
        t_s=t,
        estimate_xy=est,
        reference_xy=ref,
        estimate_yaw_rad=yaw,
        nees=nees,
        in_outage=inside,
        valid=valid,
        ape=ape_statistics(err),
        p95_error_m=float(np.percentile(err, 95)),
        nees_within_bound=float(np.mean(nees <= CHI2_2DOF_95)),
        offered_fixes=offered,
        rejected_fixes=ekf.rejected_fixes,
        resets=ekf.resets,
        outages=tuple(results),
        used_accelerometer=accel,
        used_wheel_speed=has_wheel,
        compute_us_per_input=us_per_input,
    )


def write_tum(path: Path, t_s: np.ndarray, xy: np.ndarray, yaw_rad: np.ndarray) -> None:
    """A TUM trajectory file (``timestamp x y z qx qy qz qw``), as evo reads it."""
    lines = [
        f"{ts:.6f} {x:.9f} {y:.9f} 0.0 0.0 0.0 {math.sin(0.5 * a):.12f} {math.cos(0.5 * a):.12f}"
        for ts, (x, y), a in zip(t_s.tolist(), xy.tolist(), yaw_rad.tolist(), strict=True)
    ]
    path.write_text("\n".join(lines) + "\n")


def summary_rows(result: ReplayResult) -> list[tuple[str, str]]:
    """(metric, value) lines of the printed report."""
    a = result.ape
    inputs = "IMU yaw rate" + (" + accelerometer" if result.used_accelerometer else "")
    inputs += " + wheel speed" if result.used_wheel_speed else ""
    rows = [
        ("mode", f"{result.mode.value} ({inputs})"),
        ("reference fixes with an estimate", str(a.count)),
        ("ATE rmse / mean / median / max (m)", f"{a.rmse:.3f} / {a.mean:.3f} / {a.median:.3f} / {a.max:.3f}"),
        ("error p95 over the run (m)", f"{result.p95_error_m:.3f}"),
        ("estimate valid (own flag)", f"{100.0 * float(result.valid.mean()):.1f} %"),
        (
            f"NEES <= {CHI2_2DOF_95:.2f} (95 % chi2, 2 dof)",
            f"{100.0 * result.nees_within_bound:.1f} % of fixes (mean NEES {float(result.nees.mean()):.2f})",
        ),
        (
            "fixes rejected (outside outages)",
            f"{result.rejected_fixes} of {result.offered_fixes} ({100.0 * result.rejected_share:.2f} %), "
            f"{result.resets} re-acquisitions",
        ),
        ("compute per input", f"{result.compute_us_per_input:.1f} µs"),
    ]
    for o in result.outages:
        name = f"outage {o.outage.start_s:g}+{o.outage.duration_s:g} s"
        reacq = "never" if o.reacquired_after_s is None else f"{o.reacquired_after_s:.2f} s"
        rows.append(
            (
                name,
                f"end error {o.end_error_m:.3f} m (lateral {o.end_lateral_m:+.3f}, longitudinal "
                f"{o.end_longitudinal_m:+.3f}), sigma {o.end_sigma_m:.3f} m, max {o.max_error_m:.3f} m, "
                f"NEES within bound {100.0 * o.nees_within_bound:.0f} %, GNSS accepted again after {reacq}",
            )
        )
    return rows


def result_json(result: ReplayResult) -> dict[str, object]:
    """The scores as JSON-able data."""
    return {
        "mode": result.mode.value,
        "ape_m": result.ape.as_dict(),
        "p95_error_m": result.p95_error_m,
        "valid_share": float(result.valid.mean()),
        "nees_within_bound": result.nees_within_bound,
        "mean_nees": float(result.nees.mean()),
        "offered_fixes": result.offered_fixes,
        "rejected_fixes": result.rejected_fixes,
        "rejected_share": result.rejected_share,
        "resets": result.resets,
        "used_accelerometer": result.used_accelerometer,
        "used_wheel_speed": result.used_wheel_speed,
        "compute_us_per_input": result.compute_us_per_input,
        "outages": [
            {
                "start_s": o.outage.start_s,
                "duration_s": o.outage.duration_s,
                "end_error_m": o.end_error_m,
                "end_lateral_m": o.end_lateral_m,
                "end_longitudinal_m": o.end_longitudinal_m,
                "end_sigma_m": o.end_sigma_m,
                "max_error_m": o.max_error_m,
                "nees_within_bound": o.nees_within_bound,
                "reacquired_after_s": o.reacquired_after_s,
            }
            for o in result.outages
        ],
    }
