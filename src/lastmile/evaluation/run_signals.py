"""The signals every metric shares, derived once from a run log, and the comfort limits checked on them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.evaluation.pose_errors import PoseErrors, pose_errors
from lastmile.recorder import run_log

RESAMPLE_PERIOD_S = 0.1
"""Window of the acceleration means that jerk and braking episodes are computed from (10 Hz)."""

_EMERGENCY_CODE = run_log.STATE_NAMES.index("emergency_stop")


@dataclass(frozen=True, kw_only=True)
class ComfortLimits:
    """Ride-comfort limits of a shuttle with standing riders, checked on the 10 Hz signals.

    nuPlan's comfort limits (2.40 / -4.05 m/s², 4.13 m/s³) are for seated car occupants. A shuttle
    carries standing riders who hold on with one hand, so the limits are tighter: 2.0 m/s² forward,
    3.0 m/s² braking, and 2.5 m/s³ jerk. Snow Lion's campus shuttle stayed inside 1.12 / -1.83 m/s² and
    ±1.93 m/s³ over 1,000 km, so a good stack can meet these with margin.

    Attributes:
        max_accel_mps2: largest comfortable forward acceleration (> 0).
        max_decel_mps2: largest comfortable braking, as a positive magnitude (> 0).
        max_abs_jerk_mps3: largest comfortable jerk magnitude (> 0).
        emergency_window_s: after an ``emergency_stop`` or ``takeover`` event, the samples this long
            are exempt from the comfort check (as are rows in the ``emergency_stop`` state): an
            emergency stop should be hard.
        hard_braking_mps2: acceleration at or below which an episode counts as hard braking (< 0).
        hard_braking_release_mps2: the episode ends once acceleration rises above
            ``hard_braking_mps2 + hard_braking_release_mps2`` (>= 0), so noise at the threshold counts once.
    """

    max_accel_mps2: float = 2.0
    max_decel_mps2: float = 3.0
    max_abs_jerk_mps3: float = 2.5
    emergency_window_s: float = 3.0
    hard_braking_mps2: float = -1.0
    hard_braking_release_mps2: float = 0.1

    def __post_init__(self) -> None:
        for name in ("max_accel_mps2", "max_decel_mps2", "max_abs_jerk_mps3"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"ComfortLimits.{name}: expected a finite number > 0, got {value!r}")
        for name in ("emergency_window_s", "hard_braking_release_mps2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"ComfortLimits.{name}: expected a finite number >= 0, got {value!r}")
        if not (math.isfinite(self.hard_braking_mps2) and self.hard_braking_mps2 < 0.0):
            got = self.hard_braking_mps2
            raise ConfigError(f"ComfortLimits.hard_braking_mps2: expected a finite number < 0, got {got!r}")


SHUTTLE_COMFORT = ComfortLimits()
"""The default comfort limits of a shuttle with standing riders."""

SNOW_LION_COMFORT = ComfortLimits(max_accel_mps2=1.12, max_decel_mps2=1.83, max_abs_jerk_mps3=1.84)
"""Snow Lion's measured envelope (its Table 2: acceleration -1.83 to 1.12 m/s², jerk up to 1.84 m/s³),
the target of issue #20's comfort check (``snow_lion_comfort_compliant``)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ComfortExceedance:
    """The worst 10 Hz sample beyond one comfort limit, outside emergencies.

    Attributes:
        limit: which limit (``max_accel_mps2``, ``max_decel_mps2`` or ``max_abs_jerk_mps3``).
        value: the worst value beyond it (m/s² or m/s³, signed as measured).
        bound: the limit it broke (signed: the deceleration bound is negative).
        t_s: when (window mean time).
        state: the behaviour state there (a name of ``run_log.STATE_NAMES``, or ``unknown``).
        windows: how many 10 Hz samples are beyond this limit.
    """

    limit: str
    value: float
    bound: float
    t_s: float
    state: str
    windows: int

    def describe(self) -> str:
        unit = "m/s^3" if self.limit == "max_abs_jerk_mps3" else "m/s^2"
        return (
            f"{self.limit}: {self.value:+.2f} {unit} beyond {self.bound:+.2f} at t {self.t_s:.1f} s "
            f"({self.state}; {self.windows} sample{'s' if self.windows != 1 else ''} of 0.1 s)"
        )


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the maximal runs of True in a 1-D bool array."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


class RunSignals:
    """A run log with the signals metrics share, each derived once on first use.

    Attributes:
        log: the run log.
        comfort: the comfort limits in force.
        t_s, x_m, y_m, speed_mps, accel_mps2: (N,) float64 ego columns.
        state: (N,) int64 behaviour state codes.
    """

    def __init__(self, log: run_log.RunLog, comfort: ComfortLimits) -> None:
        self.log = log
        self.comfort = comfort
        self.t_s = log.column("t_s")
        self.x_m = log.column("x_m")
        self.y_m = log.column("y_m")
        self.speed_mps = log.column("speed_mps")
        self.accel_mps2 = log.column("accel_mps2")
        self.state = log.column("state_code").astype(np.int64)

    @property
    def rows(self) -> int:
        return len(self.t_s)

    @cached_property
    def pose_errors(self) -> PoseErrors:
        """Localization and cross-track errors per localization-table row."""
        return pose_errors(self.log)

    @cached_property
    def dt_s(self) -> np.ndarray:
        """(N-1,) time from each sample to the next; sample i holds its values for dt_s[i]."""
        return np.diff(self.t_s)

    @cached_property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0]) if self.rows >= 2 else 0.0

    @cached_property
    def distance_m(self) -> float:
        return float(np.sum(np.hypot(np.diff(self.x_m), np.diff(self.y_m))))

    def time_where(self, mask: np.ndarray) -> float:
        """Seconds during which the (N,) row mask holds, each row holding until the next."""
        if self.rows < 2:
            return 0.0
        return float(np.sum(self.dt_s[mask[:-1]]))

    def events(self, kind: str) -> tuple[run_log.RunEvent, ...]:
        return self._by_kind.get(kind, ())

    @cached_property
    def _by_kind(self) -> dict[str, tuple[run_log.RunEvent, ...]]:
        grouped: dict[str, list[run_log.RunEvent]] = {}
        for event in self.log.events:
            grouped.setdefault(event.kind, []).append(event)
        return {k: tuple(v) for k, v in grouped.items()}

    def config_number(self, key: str) -> float | None:
        """A number from ``meta.config`` (None when absent).

        Raises:
            ConfigError: the key is present but not a finite number.
        """
        if key not in self.log.meta.config:
            return None
        value = self.log.meta.config[key]
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ConfigError(f"meta.config.{key}: expected a finite number, got {value!r}")
        return float(value)

    # --- the 10 Hz signals ----------------------------------------------------------------------
    @cached_property
    def emergency_rows(self) -> np.ndarray:
        """(N,) bool: rows in the emergency-stop state or within the window after an emergency or takeover."""
        mask = self.state == _EMERGENCY_CODE
        window = self.comfort.emergency_window_s
        for event in (*self.events("emergency_stop"), *self.events("takeover")):
            mask |= (self.t_s >= event.t_s) & (self.t_s <= event.t_s + window)
        return mask

    @cached_property
    def _windows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Window means: (K,) window index, mean time, mean acceleration, any-emergency flag."""
        if self.rows == 0:
            empty = np.zeros(0)
            return empty.astype(np.int64), empty, empty, empty.astype(bool)
        # The small offset keeps a sample that lands on a window edge (0.1 s, 0.2 s, ...) in the later
        # window despite binary rounding of the tick.
        index = np.floor((self.t_s - self.t_s[0]) / RESAMPLE_PERIOD_S + 1e-6).astype(np.int64)
        windows, inverse, counts = np.unique(index, return_inverse=True, return_counts=True)
        t_mean = np.bincount(inverse, weights=self.t_s) / counts
        a_mean = np.bincount(inverse, weights=self.accel_mps2) / counts
        emergency = np.bincount(inverse, weights=self.emergency_rows.astype(float)) > 0.0
        return windows, t_mean, a_mean, emergency

    @property
    def accel_10hz_mps2(self) -> np.ndarray:
        """(K,) acceleration averaged over each 0.1 s window that holds samples."""
        return self._windows[2]

    @property
    def accel_10hz_t_s(self) -> np.ndarray:
        return self._windows[1]

    @cached_property
    def _jerk(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        windows, t_mean, a_mean, emergency = self._windows
        # Differentiate only between adjacent windows: across a gap in the trace there is no estimate.
        adjacent = np.diff(windows) == 1
        jerk = (np.diff(a_mean) / np.diff(t_mean))[adjacent] if len(windows) > 1 else np.zeros(0)
        t_mid = (0.5 * (t_mean[1:] + t_mean[:-1]))[adjacent] if len(windows) > 1 else np.zeros(0)
        excluded = (emergency[1:] | emergency[:-1])[adjacent] if len(windows) > 1 else np.zeros(0, bool)
        return t_mid, jerk, excluded

    @property
    def jerk_mps3(self) -> np.ndarray:
        """(K-1,) jerk between adjacent 0.1 s windows (fewer where the trace has gaps)."""
        return self._jerk[1]

    @property
    def jerk_t_s(self) -> np.ndarray:
        return self._jerk[0]

    @cached_property
    def hard_braking_events(self) -> int:
        enter = self.comfort.hard_braking_mps2
        leave = enter + self.comfort.hard_braking_release_mps2
        count, braking = 0, False
        for a in self.accel_10hz_mps2.tolist():
            if not braking and a <= enter:
                count, braking = count + 1, True
            elif braking and a > leave:
                braking = False
        return count

    @cached_property
    def comfort_accel_mps2(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_s, accel): the 10 Hz acceleration outside emergencies (what the comfort check reads)."""
        keep = ~self._windows[3]
        return self.accel_10hz_t_s[keep], self.accel_10hz_mps2[keep]

    @cached_property
    def comfort_jerk_mps3(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_s, jerk): the 10 Hz jerk outside emergencies (what the comfort check reads)."""
        keep = ~self._jerk[2]
        return self.jerk_t_s[keep], self.jerk_mps3[keep]

    def comfort_exceedances(self, limits: ComfortLimits | None = None) -> list[ComfortExceedance]:
        """Per limit broken, its worst sample (empty when comfortable); ``limits`` default to the run's."""
        c = limits or self.comfort
        t_a, a = self.comfort_accel_mps2
        t_j, j = self.comfort_jerk_mps3
        checks = (
            ("max_accel_mps2", t_a, a, a - c.max_accel_mps2, c.max_accel_mps2),
            ("max_decel_mps2", t_a, a, -c.max_decel_mps2 - a, -c.max_decel_mps2),
            ("max_abs_jerk_mps3", t_j, j, np.abs(j) - c.max_abs_jerk_mps3, c.max_abs_jerk_mps3),
        )
        out = []
        for name, t, values, excess, bound in checks:
            over = excess > 0.0
            if not np.any(over):
                continue
            worst = int(np.argmax(excess))
            value = float(values[worst])
            row = min(int(np.searchsorted(self.t_s, t[worst])), self.rows - 1)
            code = int(self.state[row])
            state = run_log.STATE_NAMES[code] if 0 <= code < len(run_log.STATE_NAMES) else "unknown"
            signed_bound = -bound if name == "max_abs_jerk_mps3" and value < 0.0 else bound
            out.append(
                ComfortExceedance(
                    limit=name,
                    value=value,
                    bound=signed_bound,
                    t_s=float(t[worst]),
                    state=state,
                    windows=int(np.count_nonzero(over)),
                )
            )
        return out

    @cached_property
    def comfort_compliant(self) -> bool:
        return not self.comfort_exceedances()

    # --- rules -----------------------------------------------------------------------------------
    def violations(self, rule: str) -> tuple[run_log.RunEvent, ...]:
        return tuple(e for e in self.events("rule_violation") if e.data.get("rule") == rule)

    @cached_property
    def over_limit_rows(self) -> np.ndarray:
        """(N,) bool: rows inside speeding episodes that the referee flagged with a violation.

        With ``speed_limit_mps`` in the config an episode is a maximal run of speed above limit plus
        tolerance, counted when a ``speed_limit`` violation falls inside it (or at the sample after
        it). Without it, the episode around each violation is the run of samples at least as fast as
        the slowest sample of the ``speed_hold_s`` before the violation, which the referee saw over the
        limit throughout: a lower-bound estimate.
        """
        mask = np.zeros(self.rows, dtype=bool)
        flagged = [e.t_s for e in self.violations("speed_limit")]
        if not flagged or self.rows == 0:
            return mask
        limit = self.config_number("speed_limit_mps")
        if limit is not None:
            tolerance = self.config_number("speed_tolerance_mps")
            threshold = limit + (0.5 if tolerance is None else tolerance)
            for start, stop in true_runs(self.speed_mps > threshold):
                t_end = self.t_s[min(stop, self.rows - 1)]
                if any(self.t_s[start] <= t <= t_end for t in flagged):
                    mask[start:stop] = True
            return mask
        hold = self.config_number("speed_hold_s")
        hold_s = 1.0 if hold is None else hold
        for t in flagged:
            at = int(np.searchsorted(self.t_s, t, side="right")) - 1
            if at < 0:
                continue
            first = int(np.searchsorted(self.t_s, t - hold_s, side="left"))
            threshold = float(np.min(self.speed_mps[first : at + 1]))
            for start, stop in true_runs(self.speed_mps >= threshold):
                if start <= at < stop:
                    mask[start:stop] = True
                    break
        return mask

    @cached_property
    def progress_ratio(self) -> float:
        expected = self.config_number("expected_distance_m")
        if expected is None:
            return 1.0
        if expected <= 0.0:
            raise ConfigError(f"meta.config.expected_distance_m: expected a number > 0, got {expected}")
        return self.distance_m / expected

    @cached_property
    def min_ttc_s(self) -> float | None:
        values = [float(e.data["ttc_s"]) for e in self.events("min_ttc")]
        return min(values) if values else None
