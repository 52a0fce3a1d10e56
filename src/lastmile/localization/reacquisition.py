"""When rejected GNSS fixes prove the filter, not the receiver, wrong: the re-acquisition rule."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from lastmile.core.stamp import US_PER_S

_MAX_FIXES = 64


@dataclass(frozen=True, slots=True)
class RejectedFix:
    """A fix the chi-square gate rejected.

    Attributes:
        t_us: its stamp, µs.
        innovation: (2,) fix minus prediction, m.
        r: (2, 2) the fix's covariance (floored at its type's accuracy), m^2.
        p_pos: (2, 2) the filter's position covariance when it arrived, m^2.
    """

    t_us: int
    innovation: np.ndarray
    r: np.ndarray
    p_pos: np.ndarray


class ReacquisitionRule:
    """Decides a reset from the fix's own covariance and the consistency of recent rejections.

    The rejected fixes must span ``window_s`` (three quarters of it, for the fix period) with at least
    ``min_fixes`` of them, each claiming by its own covariance to be better than the filter, and they
    must agree on one offset: their innovations about their mean, weighted by each fix's covariance
    plus the filter's own position drift since that fix, pass a chi-square test at ``quantile`` with
    2(n-1) degrees of freedom. A drifted filter sees one steady offset; multipath and a wandering
    receiver do not. Any accepted fix clears the record.
    """

    def __init__(self, window_s: float, min_fixes: int, quantile: float) -> None:
        self._window_us = round(window_s * US_PER_S)
        self._min_fixes = min_fixes
        self._rejected: deque[RejectedFix] = deque(maxlen=_MAX_FIXES)
        self._bound = [float("inf")] + [float(chi2.ppf(quantile, 2 * n)) for n in range(1, _MAX_FIXES)]

    def clear(self) -> None:
        self._rejected.clear()

    def reject(self, fix: RejectedFix, p_pos_now: np.ndarray) -> bool:
        """Record a rejected fix; True when the filter should restart from it (the record is cleared)."""
        self._rejected.append(fix)
        if self._consistent(p_pos_now):
            self._rejected.clear()
            return True
        return False

    def _consistent(self, p_now: np.ndarray) -> bool:
        newest = self._rejected[-1].t_us
        recent = [f for f in self._rejected if newest - f.t_us <= self._window_us]
        if len(recent) < self._min_fixes or newest - recent[0].t_us < 0.75 * self._window_us:
            return False
        filter_var = float(np.linalg.eigvalsh(p_now)[-1])
        if any(float(np.linalg.eigvalsh(f.r)[-1]) >= filter_var for f in recent):
            return False
        innovations = np.array([f.innovation for f in recent])
        mean = innovations.mean(axis=0)
        stat = 0.0
        for f, nu in zip(recent, innovations, strict=True):
            drift = p_now - f.p_pos
            drift = 0.5 * (drift + drift.T)
            vals, vecs = np.linalg.eigh(drift)
            drift = (vecs * np.clip(vals, 0.0, None)) @ vecs.T
            dev = nu - mean
            stat += float(dev @ np.linalg.solve(f.r + drift, dev))
        return stat <= self._bound[len(recent) - 1]
