"""The signals every metric shares, derived once from a run log, and the comfort limits checked on them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from lastmile.core.errors import ConfigError
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
    def comfort_compliant(self) -> bool:
        c = self.comfort
        keep_a = ~self._windows[3]
        accel = self.accel_10hz_mps2[keep_a]
        jerk = self.jerk_mps3[~self._jerk[2]]
        return bool(
            np.all(accel <= c.max_accel_mps2)
            and np.all(accel >= -c.max_decel_mps2)
            and np.all(np.abs(jerk) <= c.max_abs_jerk_mps3)
        )

    def comfort_exceedances(self) -> list[str]:
        """Why :attr:`comfort_compliant` is false: per limit broken, the worst sample, when, and how many
        0.1 s samples broke it (emergency windows exempt, as in the check). Empty when compliant."""
        c = self.comfort
        keep_a = ~self._windows[3]
        t_a, accel = self.accel_10hz_t_s[keep_a], self.accel_10hz_mps2[keep_a]
        t_j, jerk = self.jerk_t_s[~self._jerk[2]], self.jerk_mps3[~self._jerk[2]]
        out = []
        for name, t, values, over, limit, unit in (
            ("acceleration", t_a, accel, accel > c.max_accel_mps2, c.max_accel_mps2, "m/s²"),
            ("braking", t_a, -accel, accel < -c.max_decel_mps2, c.max_decel_mps2, "m/s²"),
            ("jerk", t_j, np.abs(jerk), np.abs(jerk) > c.max_abs_jerk_mps3, c.max_abs_jerk_mps3, "m/s³"),
        ):
            if over.any():
                worst = int(np.argmax(np.where(over, values, -np.inf)))
                out.append(
                    f"{name} {values[worst]:.2f} {unit} at {t[worst]:.1f} s exceeds {limit:.2f} "
                    f"({int(over.sum())} samples of 0.1 s over)"
                )
        return out

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
