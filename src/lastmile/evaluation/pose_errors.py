"""Localization error (the stack's estimate against the true pose) and cross-track error over a run.

Reads the run log's localization table (``recorder/run_localization.py``): one row per planning cycle
with the estimate the stack reported and the true pose at the same instant. The error is split in the
true pose's own frame: along-track (ahead positive) and lateral (left positive). The stack's 1.96-sigma
band uses its reported position sigma (the sigma of the covariance's largest horizontal axis, so a
bound on each axis's sigma): a consistent filter keeps each axis's error inside it at least 95 % of
the time.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from lastmile.recorder.run_localization import INVALID_SOURCE, POSITION_SOURCES
from lastmile.recorder.run_log import STATE_NAMES, RunLog

IN_LANE_STATES = (STATE_NAMES.index("normal_driving"), STATE_NAMES.index("intersection"))
"""Behaviour-state codes in which the shuttle means to follow the route's centre line (pull-overs,
stops at the curb and merges leave it on purpose)."""

BAND_SIGMAS = 1.96
"""Half-width of the stack's band in sigmas: the two-sided 95 % interval of a Gaussian axis."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseErrors:
    """Errors per localization row (all (M,) float64; NaN where the estimate was invalid or unknown).

    Attributes:
        t_s: simulated time.
        along_m: estimate minus truth along the true heading, m (ahead positive).
        lateral_m: estimate minus truth across it, m (left positive).
        total_m: horizontal distance between estimate and truth, m.
        band_m: the stack's reported 1.96-sigma position band, m.
        source_code: (M,) int64, index into ``POSITION_SOURCES``, -1 when the estimate was invalid.
        route_d_m: the true rear axle's signed offset from the route's centre line, m.
        path_d_m: the true rear axle's signed offset from the latest planned path, m.
        in_lane: (M,) bool, the behaviour state (the ego trace's latest at or before the row) was one
            of :data:`IN_LANE_STATES`.
    """

    t_s: np.ndarray
    along_m: np.ndarray
    lateral_m: np.ndarray
    total_m: np.ndarray
    band_m: np.ndarray
    source_code: np.ndarray
    route_d_m: np.ndarray
    path_d_m: np.ndarray
    in_lane: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def valid(self) -> np.ndarray:
        """(M,) bool: rows whose estimate the stack flagged valid."""
        return self.source_code != INVALID_SOURCE


def pose_errors(log: RunLog) -> PoseErrors:
    """The errors of every row of the log's localization table (empty for a log without one)."""
    loc = log.localization
    code = loc.column("source_code").astype(np.int64)
    valid = code != INVALID_SOURCE
    ex = np.where(valid, loc.column("est_x_m") - loc.column("true_x_m"), np.nan)
    ey = np.where(valid, loc.column("est_y_m") - loc.column("true_y_m"), np.nan)
    yaw = loc.column("true_yaw_rad")
    t = loc.column("t_s")
    ego_t = log.column("t_s")
    row = np.clip(np.searchsorted(ego_t, t, side="right") - 1, 0, max(len(ego_t) - 1, 0))
    state = log.column("state_code")[row] if len(ego_t) else np.full(len(t), -1.0)
    c, s = np.cos(yaw), np.sin(yaw)
    return PoseErrors(
        t_s=loc.column("t_s").copy(),
        along_m=c * ex + s * ey,
        lateral_m=-s * ex + c * ey,
        total_m=np.hypot(ex, ey),
        band_m=np.where(valid, BAND_SIGMAS * loc.column("pos_std_m"), np.nan),
        source_code=code,
        route_d_m=loc.column("route_d_m").copy(),
        path_d_m=loc.column("path_d_m").copy(),
        in_lane=np.isin(state, IN_LANE_STATES),
    )


def source_spans(errors: PoseErrors) -> list[tuple[float, float, str]]:
    """``(start_s, end_s, source)`` runs of one position source ("invalid" for invalid estimates);
    each run ends where the next begins (the last at the last row)."""
    t, code = errors.t_s, errors.source_code
    if len(t) == 0:
        return []
    cuts = np.flatnonzero(np.diff(code)) + 1
    starts = np.concatenate([[0], cuts])
    ends = np.concatenate([cuts, [len(t) - 1]])
    return [(float(t[a]), float(t[b]), source_name(int(code[a]))) for a, b in zip(starts, ends, strict=True)]


def source_name(code: int) -> str:
    """The ``PositionSource`` value of a ``source_code``, "invalid" for -1."""
    return "invalid" if code == INVALID_SOURCE else POSITION_SOURCES[code]


def _finite_abs(values: np.ndarray) -> np.ndarray:
    a = np.abs(values)
    return a[np.isfinite(a)]


def _p95(values: np.ndarray) -> float | None:
    a = _finite_abs(values)
    return float(np.percentile(a, 95.0)) if len(a) else None


def _max(values: np.ndarray) -> float | None:
    a = _finite_abs(values)
    return float(a.max()) if len(a) else None


def _outside_band_share(e: PoseErrors) -> float | None:
    ok = e.valid & np.isfinite(e.lateral_m) & np.isfinite(e.band_m)
    if not ok.any():
        return None
    return float(np.mean(np.abs(e.lateral_m[ok]) > e.band_m[ok]))


POSE_METRICS: Mapping[str, Callable[[PoseErrors], float | None]] = MappingProxyType(
    {
        "localization_error_p95_m": lambda e: _p95(e.total_m),
        "localization_error_max_m": lambda e: _max(e.total_m),
        "localization_lateral_error_p95_m": lambda e: _p95(e.lateral_m),
        "localization_lateral_error_max_m": lambda e: _max(e.lateral_m),
        "localization_along_error_p95_m": lambda e: _p95(e.along_m),
        "localization_along_error_max_m": lambda e: _max(e.along_m),
        "localization_lateral_outside_band_share": _outside_band_share,
        "cross_track_error_path_p95_m": lambda e: _p95(e.path_d_m),
        "cross_track_error_path_max_m": lambda e: _max(e.path_d_m),
        "cross_track_error_route_p95_m": lambda e: _p95(e.route_d_m[e.in_lane]),
        "cross_track_error_route_max_m": lambda e: _max(e.route_d_m[e.in_lane]),
    }
)
"""The summary figures ``metrics.json`` gains (None where the log has no valid row to measure):
p95 and maximum of the absolute total, lateral and along-track localization error over valid
estimates; the share of valid estimates whose lateral error leaves the stack's 1.96-sigma band (at
most about 0.05 for a consistent filter); p95 and maximum of the true cross-track error against the
planned path (what the controllers track) and against the route's centre line while in lane (normal
driving or an intersection: pull-overs, curb stops and merges leave the centre line on purpose)."""
