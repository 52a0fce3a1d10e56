"""Snow Lion's speed planning: a search on the s-t graph over predicted obstacles, refined by a QP.

"Predicted trajectories of dynamic obstacles are projected relative to this path, and an s-t graph is
formulated. We then utilize a breadth-first search on this graph to identify an initial speed profile,
which is later refined using piecewise polynomials through a quadratic programming problem."

Search: layers every ``search_dt_s``; states (station, speed) on a grid; from each, a handful of constant
accelerations; a state is dropped when its step crosses an obstacle's occupied interval (with the
following gap) or exceeds the speed limit; the cost tracks the limit profile and penalises acceleration
and its change. The search decides, per obstacle, whether to pass before it or yield behind it.
QP: piecewise-jerk profile (stations, speeds, accelerations every ``qp_dt_s``; jerk constant between
knots), bounded by the corridor the search chose, the speed limit at the search's stations, the
acceleration and jerk limits; solved with OSQP whose workspace is built once (its constraint matrix is
constant: only the bounds and the linear cost change) and warm-started.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.sparse as sp

from lastmile.core.errors import ConfigError, MessageError


@dataclass(frozen=True, slots=True, kw_only=True)
class StObstacle:
    """An obstacle's predicted occupancy of the path: at time t_s[k] it covers [s_lo_m[k], s_hi_m[k]].

    Attributes:
        t_s: (K,) float64 increasing times from now (s); outside [t_s[0], t_s[-1]] it occupies nothing.
        s_lo_m, s_hi_m: (K,) float64 path stations of its rear and front (already inflated).
    """

    t_s: np.ndarray
    s_lo_m: np.ndarray
    s_hi_m: np.ndarray

    def validate(self) -> None:
        t, lo, hi = (np.asarray(a, dtype=np.float64) for a in (self.t_s, self.s_lo_m, self.s_hi_m))
        if t.ndim != 1 or lo.shape != t.shape or hi.shape != t.shape or len(t) == 0:
            raise MessageError(
                f"StObstacle: expected three (K,) arrays, got {t.shape}, {lo.shape}, {hi.shape}"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.diff(t) >= 0.0) and np.all(hi >= lo)):
            raise MessageError("StObstacle: expected finite increasing times and s_hi_m >= s_lo_m")

    def speed_at(self, t_s: float) -> float:
        """Its speed along the path (m/s, >= 0) at ``t_s``: the slope of its rear over a 0.1 s window."""
        ta, tb = max(self.t_s[0], t_s - 0.05), min(self.t_s[-1], t_s + 0.05)
        if tb <= ta:
            return 0.0
        ds = float(np.interp(tb, self.t_s, self.s_lo_m) - np.interp(ta, self.t_s, self.s_lo_m))
        return max(0.0, ds / (tb - ta))

    def interval_at(self, t_s: float) -> tuple[float, float] | None:
        if t_s < self.t_s[0] or t_s > self.t_s[-1]:
            return None
        return float(np.interp(t_s, self.t_s, self.s_lo_m)), float(np.interp(t_s, self.t_s, self.s_hi_m))


@dataclass(frozen=True, slots=True, kw_only=True)
class StSpeedConfig:
    """Horizon, grids, limits and weights.

    Attributes:
        horizon_s: planning horizon.
        max_speed_mps: cap on every limit (the shuttle's top speed).
        search_dt_s, search_ds_m, search_dv_mps: the s-t search's time step and state grid (coarse:
            the search picks which side of each obstacle to pass, the QP shapes the profile).
        search_accels_mps2: accelerations tried from every state.
        qp_dt_s: knot spacing of the QP.
        max_accel_mps2, max_decel_mps2, max_jerk_mps3: limits (inside Snow Lion's measured comfort
            envelope: -1.83 to 1.12 m/s^2, |jerk| <= 1.84 m/s^3).
        follow_gap_m: gap kept behind an obstacle's rear and ahead of its front.
        headway_s: behind an obstacle, s + headway * v <= its rear - gap + headway * its speed: closing
            in faster than it moves needs room in proportion (so the horizon never ends at the gap at a
            speed the next plan cannot shed comfortably).
        closing_s: behind an obstacle the QP aims at its speed plus the room beyond the following
            distance (gap + headway x its speed) divided by this (a time-gap controller's closing
            time; 4 s closes a 4 m surplus at 1 m/s faster).
        w_speed, w_accel, w_jerk, w_guide: QP weights on the speed error (to the limit), acceleration,
            jerk and distance to the search's stations.
        eps, max_iter: OSQP tolerance and iteration cap.
    """

    horizon_s: float = 8.0
    max_speed_mps: float = 20.0 / 3.6
    search_dt_s: float = 1.0
    search_ds_m: float = 0.5
    search_dv_mps: float = 0.5
    search_accels_mps2: tuple[float, ...] = (-1.5, -1.0, -0.5, 0.0, 0.5, 1.0)
    qp_dt_s: float = 0.2
    max_accel_mps2: float = 1.0
    max_decel_mps2: float = 1.5
    max_jerk_mps3: float = 1.8
    follow_gap_m: float = 3.0
    headway_s: float = 1.5
    closing_s: float = 4.0
    w_speed: float = 1.0
    w_accel: float = 1.0
    w_jerk: float = 1.0
    w_guide: float = 0.01
    eps: float = 1e-5
    max_iter: int = 10_000

    def __post_init__(self) -> None:
        for name in ("horizon_s", "search_dt_s", "search_ds_m", "search_dv_mps", "qp_dt_s", "max_jerk_mps3"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"StSpeedConfig.{name}: expected a positive number, got {value}")
        if self.horizon_s < 2 * self.search_dt_s:
            raise ConfigError(
                f"StSpeedConfig: expected horizon_s >= 2 search steps, got {self.horizon_s} s "
                f"and {self.search_dt_s} s"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class SpeedPlan:
    """A speed profile along the path.

    Attributes:
        t_s, s_m, v_mps, a_mps2: (M+1,) float64 knots from now.
        jerk_mps3: (M,) float64 constant jerk between knots.
        solved: the QP was solved; False means no comfortable profile fits the corridor and the plan
            is the search's (or a full-deceleration stop when the search found none).
        search_s_m: (L+1,) the search's stations every ``search_dt_s`` (NaN when it found none).
    """

    t_s: np.ndarray
    s_m: np.ndarray
    v_mps: np.ndarray
    a_mps2: np.ndarray
    jerk_mps3: np.ndarray
    solved: bool
    search_s_m: np.ndarray


def _blocked(
    obstacles: list[StObstacle], t0: float, t1: float, s0: np.ndarray, s1: np.ndarray, gap: float
) -> np.ndarray:
    """Whether each step from (t0, s0) to (t1, s1) overlaps an obstacle's interval (with the gap)."""
    lo_s, hi_s = np.minimum(s0, s1), np.maximum(s0, s1)
    out = np.zeros(s0.shape, dtype=bool)
    for ob in obstacles:
        # Both ends and the middle of the step: an obstacle crossing the path must not slip between.
        for t in (t0, 0.5 * (t0 + t1), t1):
            iv = ob.interval_at(t)
            if iv is not None:
                out |= (hi_s >= iv[0] - gap) & (lo_s <= iv[1] + gap)
    return out


def _braking_speed(t: np.ndarray, v0: float, a0: float, decel: float, jerk: float) -> np.ndarray:
    """The speed at ``t`` braking as hard as allowed: the acceleration falls from ``a0`` at ``jerk``
    to ``-decel``, then holds (never below rest)."""
    a0 = max(a0, -decel)
    t_ramp = (a0 + decel) / jerk
    v_ramp = v0 + a0 * t_ramp - 0.5 * jerk * t_ramp**2
    v = np.where(t < t_ramp, v0 + a0 * t - 0.5 * jerk * t**2, v_ramp - decel * (t - t_ramp))
    return np.maximum(v, 0.0)


def st_search(
    limit_s_m: np.ndarray,
    limit_v_mps: np.ndarray,
    v0_mps: float,
    obstacles: list[StObstacle],
    c: StSpeedConfig,
) -> np.ndarray | None:
    """The search's stations (L+1,) every ``search_dt_s`` from 0, or None when every path is blocked.

    ``limit_v_mps`` (at stations ``limit_s_m``) is the speed limit; stations start at the vehicle (0).
    """
    layers = round(c.horizon_s / c.search_dt_s)
    dt = c.search_dt_s
    v_top = float(np.max(limit_v_mps[np.isfinite(limit_v_mps)], initial=v0_mps))
    n_v = math.ceil(max(v_top, v0_mps) / c.search_dv_mps) + 2
    s_max = max(v_top, v0_mps) * c.horizon_s + 1.0
    n_s = math.ceil(s_max / c.search_ds_m) + 2
    cost = np.full((n_s, n_v), np.inf)
    s_val = np.zeros((n_s, n_v))
    cost[0, min(round(v0_mps / c.search_dv_mps), n_v - 1)] = 0.0
    v_grid = np.arange(n_v) * c.search_dv_mps
    parents: list[np.ndarray] = []
    stations: list[np.ndarray] = [s_val]
    accels = np.asarray(c.search_accels_mps2)
    for k in range(layers):
        live = np.flatnonzero(np.isfinite(cost).ravel())
        si, vi = np.unravel_index(live, cost.shape)
        s, v, c0 = s_val[si, vi], v_grid[vi], cost[si, vi]
        # Every (state, acceleration) pair at once: (A, L) arrays, flattened.
        v1 = np.maximum(v[None, :] + accels[:, None] * dt, 0.0)
        s1 = s[None, :] + 0.5 * (v[None, :] + v1) * dt
        lim = np.interp(s1, limit_s_m, limit_v_mps)
        src = np.broadcast_to(np.arange(len(live)), v1.shape)
        # A start above the limit (the cap fell, a bay's 3.5 m/s at 5.5 m/s) is shed at full
        # deceleration, not a dead end for every state (the QP's bounds allow the same).
        shed = v0_mps - c.max_decel_mps2 * (k + 1) * dt + 0.5 * c.search_dv_mps  # the grid's rounding
        ok = v1 <= np.maximum(lim, shed) + 1e-9
        s0b = np.broadcast_to(s, s1.shape)
        ok[ok] = ~_blocked(obstacles, k * dt, (k + 1) * dt, s0b[ok], s1[ok], c.follow_gap_m)
        step = c.w_speed * (np.minimum(lim, v_top) - v1) ** 2 + c.w_accel * (accels[:, None] ** 2)
        cand = (c0[None, :] + step * dt)[ok]
        s1, v1, src = s1[ok], v1[ok], src[ok]
        new_cost = np.full((n_s, n_v), np.inf)
        new_s = np.zeros((n_s, n_v))
        parent = np.full((n_s, n_v), -1, dtype=np.int64)
        if len(cand):
            ti = np.minimum(np.round(s1 / c.search_ds_m).astype(np.int64), n_s - 1)
            tv = np.minimum(np.round(v1 / c.search_dv_mps).astype(np.int64), n_v - 1)
            flat = ti * n_v + tv
            # The cheapest candidate per target cell: the first of its group sorted by (cell, cost).
            order = np.lexsort((cand, flat))
            fs = flat[order]
            head = np.ones(len(fs), dtype=bool)
            head[1:] = fs[1:] != fs[:-1]
            pick = order[head]
            new_cost.ravel()[flat[pick]] = cand[pick]
            new_s.ravel()[flat[pick]] = s1[pick]
            parent.ravel()[flat[pick]] = live[src[pick]]
        cost, s_val = new_cost, new_s
        parents.append(parent)
        stations.append(s_val)
        if not np.isfinite(cost).any():
            return None
    cell = int(np.argmin(cost))
    out = [float(stations[-1].ravel()[cell])]
    for k in range(layers - 1, -1, -1):
        cell = int(parents[k].ravel()[cell])
        out.append(float(stations[k].ravel()[cell]))
    return np.asarray(out[::-1])


class StSpeedPlanner:
    """Search, then the piecewise-jerk QP; one OSQP workspace reused across calls (warm-started)."""

    def __init__(self, config: StSpeedConfig | None = None) -> None:
        self.config = c = config or StSpeedConfig()
        self.knots = m = round(c.horizon_s / c.qp_dt_s)
        n1 = m + 1
        self._n1 = n1
        dt = c.qp_dt_s
        k = np.arange(m)
        iv, ia = n1, 2 * n1  # offsets of v and a
        jerk = sp.coo_matrix(
            (np.r_[-np.ones(m), np.ones(m)] / dt, (np.r_[k, k], np.r_[ia + k, ia + k + 1])), shape=(m, 3 * n1)
        )
        h = sp.diags(np.r_[np.full(n1, c.w_guide), np.full(n1, c.w_speed), np.full(n1, c.w_accel)])
        self._p = sp.triu(2.0 * (h + c.w_jerk * (jerk.T @ jerk)), format="csc")
        # Dynamics (piecewise-constant jerk): s' = s + v dt + a dt^2/3 + a' dt^2/6, v' = v + (a + a') dt/2.
        rows = np.r_[k, k, k, k, m + k, m + k, m + k, m + k]
        cols = np.r_[k + 1, k, iv + k, ia + k, iv + k + 1, iv + k, ia + k, ia + k + 1]
        vals = np.r_[
            np.ones(m), -np.ones(m), np.full(m, -dt), np.full(m, -dt * dt / 3.0),
            np.ones(m), -np.ones(m), np.full(m, -dt / 2.0), np.full(m, -dt / 2.0),
        ]  # fmt: skip
        # The ``a'`` term of the station row.
        rows = np.r_[rows, k]
        cols = np.r_[cols, ia + k + 1]
        vals = np.r_[vals, np.full(m, -dt * dt / 6.0)]
        dyn = sp.coo_matrix((vals, (rows, cols)), shape=(2 * m, 3 * n1))
        # Headway rows s_k + tau v_k <= s_limit_k + tau v_obstacle_k (only bounded behind an obstacle).
        headway = sp.hstack([sp.identity(n1), c.headway_s * sp.identity(n1), sp.csc_matrix((n1, n1))])
        self._a = sp.vstack([sp.identity(3 * n1), dyn, jerk, headway], format="csc")
        self._solver: osqp.OSQP | None = None

    def plan(
        self,
        limit_s_m: np.ndarray,
        limit_v_mps: np.ndarray,
        v0_mps: float,
        a0_mps2: float,
        obstacles: list[StObstacle] | None = None,
    ) -> SpeedPlan:
        """The profile from station 0 at speed ``v0_mps`` and acceleration ``a0_mps2``.

        ``limit_v_mps`` at stations ``limit_s_m`` (increasing, from 0) is the speed limit (e.g.
        ``speed_limits.combined_speed_limit_mps``); beyond its last station it holds its last value.
        """
        c = self.config
        obstacles = obstacles or []
        for ob in obstacles:
            ob.validate()
        ls, lv = np.asarray(limit_s_m, dtype=np.float64), np.asarray(limit_v_mps, dtype=np.float64)
        if ls.ndim != 1 or lv.shape != ls.shape or len(ls) < 2 or np.any(np.diff(ls) <= 0.0):
            raise MessageError(
                f"StSpeedPlanner.plan: expected (L,) increasing stations and limits, "
                f"got {ls.shape}, {lv.shape}"
            )
        if not (math.isfinite(v0_mps) and v0_mps >= 0.0 and math.isfinite(a0_mps2)):
            raise MessageError(
                f"StSpeedPlanner.plan: expected v0 >= 0 and a finite a0, got {v0_mps}, {a0_mps2}"
            )
        if np.any(np.isnan(lv)) or np.any(lv < 0.0):
            raise MessageError("StSpeedPlanner.plan: expected speed limits >= 0 m/s, got NaN or a negative")
        # Infinite limits (straight road under eq. 1) become the vehicle's top speed: the search grid
        # is sized by the highest limit.
        lv = np.minimum(lv, c.max_speed_mps)
        search = st_search(ls, lv, v0_mps, obstacles, c)
        t = np.arange(self._n1) * c.qp_dt_s
        if search is None:
            return self._full_stop(t, v0_mps, np.full(1, np.nan))
        t_search = np.arange(len(search)) * c.search_dt_s
        guide = np.interp(t, t_search, search)
        lo, hi, q = self._bounds(t, guide, ls, lv, v0_mps, a0_mps2, obstacles)
        if self._solver is None:
            self._solver = osqp.OSQP()
            self._solver.setup(
                self._p, q, self._a, lo, hi, eps_abs=c.eps, eps_rel=c.eps, max_iter=c.max_iter,
                polishing=True, warm_starting=True, verbose=False,
            )  # fmt: skip
        else:
            self._solver.update(q=q, l=lo, u=hi)
        res = self._solver.solve(raise_error=False)
        if str(res.info.status) not in ("solved", "solved inaccurate"):
            return self._from_search(search, t_search, c)
        x = np.asarray(res.x)
        n1 = self._n1
        s, v, a = x[:n1], np.maximum(x[n1 : 2 * n1], 0.0), x[2 * n1 :]
        return SpeedPlan(
            t_s=t, s_m=s, v_mps=v, a_mps2=a, jerk_mps3=np.diff(a) / c.qp_dt_s, solved=True, search_s_m=search
        )

    def _bounds(
        self,
        t: np.ndarray,
        guide: np.ndarray,
        ls: np.ndarray,
        lv: np.ndarray,
        v0: float,
        a0: float,
        obstacles: list[StObstacle],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c, n1, m = self.config, self._n1, self.knots
        s_lo = np.zeros(n1)
        s_hi = np.full(n1, 1e6)
        head_hi = np.full(n1, 1e9)
        v_follow = np.full(n1, np.inf)
        for k, tk in enumerate(t):
            for ob in obstacles:
                iv = ob.interval_at(float(tk))
                if iv is None:
                    continue
                if iv[0] - c.follow_gap_m >= guide[k] - 1e-6:
                    s_hi[k] = min(s_hi[k], iv[0] - c.follow_gap_m)
                    v_ob = ob.speed_at(float(tk))
                    if k > 0:  # the current state is given: a violated headway there is no choice
                        head_hi[k] = min(head_hi[k], iv[0] - c.follow_gap_m + c.headway_s * v_ob)
                    # Behind it, the speed aimed at is its own plus the room beyond the following
                    # distance closed over ``closing_s`` (aiming at the limit instead closed in at
                    # full acceleration and overshot: +-1 m/s around a car at 3 m/s).
                    room = iv[0] - c.follow_gap_m - c.headway_s * v_ob - guide[k]
                    v_follow[k] = min(v_follow[k], v_ob + max(room, 0.0) / c.closing_s)
                elif iv[1] + c.follow_gap_m <= guide[k] + 1e-6:
                    s_lo[k] = max(s_lo[k], iv[1] + c.follow_gap_m)
        v_lim = np.interp(guide, ls, lv)
        # An initial overspeed is shed at full deceleration, reached at the jerk limit from the
        # current acceleration, rather than making the problem infeasible (a cap falling from 5.5 to
        # 3.5 m/s ahead of a bay: with the bound v0 - D t the first knots were out of reach).
        v_hi = np.maximum(v_lim, _braking_speed(t, v0, a0, c.max_decel_mps2, c.max_jerk_mps3) + 0.05)
        lo = np.concatenate(
            [
                s_lo,
                np.zeros(n1),
                np.full(n1, -c.max_decel_mps2),
                np.zeros(2 * m),
                np.full(m, -c.max_jerk_mps3),
                np.full(n1, -1e9),
            ]
        )
        hi = np.concatenate(
            [s_hi, v_hi, np.full(n1, c.max_accel_mps2), np.zeros(2 * m), np.full(m, c.max_jerk_mps3), head_hi]
        )
        lo[0] = hi[0] = 0.0
        lo[n1] = hi[n1] = v0
        lo[2 * n1] = hi[2 * n1] = a0
        v_aim = np.minimum(v_lim, v_follow)
        q = np.concatenate([-2.0 * c.w_guide * guide, -2.0 * c.w_speed * v_aim, np.zeros(n1)])
        return lo, hi, q

    def _from_search(self, search: np.ndarray, t_search: np.ndarray, c: StSpeedConfig) -> SpeedPlan:
        v = np.gradient(search, c.search_dt_s)
        a = np.gradient(v, c.search_dt_s)
        return SpeedPlan(
            t_s=t_search, s_m=search, v_mps=np.maximum(v, 0.0), a_mps2=a,
            jerk_mps3=np.diff(a) / c.search_dt_s, solved=False, search_s_m=search,
        )  # fmt: skip

    def _full_stop(self, t: np.ndarray, v0: float, search: np.ndarray) -> SpeedPlan:
        d = self.config.max_decel_mps2
        v = np.maximum(v0 - d * t, 0.0)
        t_stop = v0 / d
        s = np.where(t < t_stop, v0 * t - 0.5 * d * t * t, v0 * v0 / (2.0 * d))
        a = np.where(v > 0.0, -d, 0.0)
        return SpeedPlan(
            t_s=t, s_m=s, v_mps=v, a_mps2=a, jerk_mps3=np.diff(a) / self.config.qp_dt_s, solved=False,
            search_s_m=search,
        )  # fmt: skip
