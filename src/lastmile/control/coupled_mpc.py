"""Snow Lion's MPC on the coupled lateral/longitudinal error model (its eqs. 3-6), solved with OSQP.

State x = [e_lat, de_lat, e_psi, de_psi, e_lon, de_lon] at the centre of gravity, input u = [delta, acc],
dx/dt = A(V_x) x + B u + C psi_dot_tar (Rajamani's dynamic bicycle, the paper's ref. [12]); e_lon is the
reference station minus ours, so acc enters with -1 and the reference acceleration as a known input.
Cost sum x'Qx + u'Ru about the steady state of the previewed curvature (so cornering needs no standing
error), subject to |delta| <= delta_max and acc_min <= acc <= acc_max (eq. 6) and, as the drive-by-wire
needs, the steering rate.

Sparse formulation over z = [x_1 .. x_N, u_0 .. u_{N-1}]: the constraint matrix's pattern is built once;
each call recomputes the exact (zero-order hold) discretisation at the current speed, writes only the
numeric values (``Ax``) and the bounds into the cached OSQP workspace, and warm-starts from the previous
solution shifted by one step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.linalg
import scipy.sparse as sp

from lastmile.control.path_errors import PathTracker, check_speed, curvature_profile, point_ahead
from lastmile.control.speed_reference import NoSpeedLaw
from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry

NX, NU = 6, 2


@dataclass(frozen=True, slots=True, kw_only=True)
class CoupledMpcConfig:
    """Horizon, vehicle parameters, weights and solver settings.

    Mass, yaw inertia and cornering stiffnesses are Rajamani's example vehicle (the paper's ref. [12],
    which Snow Lion follows; the paper does not publish its own). The weights follow Bryson's rule,
    Q_ii = 1 / (acceptable x_i)^2 and R_jj = 1 / (acceptable u_j)^2, with the acceptable values below.

    Attributes:
        horizon_steps: N.
        step_s: prediction step (N * step_s is the horizon in time).
        mass_kg, yaw_inertia_kgm2: m and I_z.
        cornering_front_npr, cornering_rear_npr: C_f and C_r (N/rad).
        cg_from_rear_axle_m: l_r; None puts the centre of gravity mid-wheelbase.
        min_model_speed_mps: V_x floor of the model (its terms divide by V_x).
        accept_*: Bryson's acceptable errors and inputs.
        accel_min_mps2, accel_max_mps2: acceleration bounds of eq. (6); None takes the vehicle's
            comfortable deceleration and its maximum acceleration.
        eps: OSQP absolute and relative tolerance (its 1e-3 default is loose for steering in radians).
        max_iter: OSQP iteration cap per solve.
    """

    horizon_steps: int = 20
    step_s: float = 0.1
    mass_kg: float = 1573.0
    yaw_inertia_kgm2: float = 2873.0
    cornering_front_npr: float = 80_000.0
    cornering_rear_npr: float = 80_000.0
    cg_from_rear_axle_m: float | None = None
    min_model_speed_mps: float = 1.0
    accept_lateral_m: float = 0.05
    accept_lateral_rate_mps: float = 0.5
    accept_heading_rad: float = 0.05
    accept_heading_rate_radps: float = 0.5
    accept_lon_m: float = 1.0
    accept_speed_mps: float = 0.5
    accept_steer_rad: float = 0.2
    accept_accel_mps2: float = 1.0
    accept_steer_step_rad: float = 0.02
    accel_min_mps2: float | None = None
    accel_max_mps2: float | None = None
    eps: float = 1e-4
    max_iter: int = 4000

    def __post_init__(self) -> None:
        if self.horizon_steps < 2 or not self.step_s > 0.0:
            raise ConfigError(
                f"CoupledMpcConfig: expected horizon_steps >= 2 and step_s > 0, "
                f"got {self.horizon_steps} and {self.step_s}"
            )
        for name in (
            "mass_kg",
            "yaw_inertia_kgm2",
            "cornering_front_npr",
            "cornering_rear_npr",
            "min_model_speed_mps",
            "eps",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"CoupledMpcConfig.{name}: expected a positive number, got {value}")


@dataclass(frozen=True, slots=True, kw_only=True)
class MpcCommand:
    """One MPC solution's first input.

    Attributes:
        steer_front_rad, steer_rear_rad: wheel angles (rear = -front with all-wheel steer, else 0).
        accel_mps2: longitudinal acceleration.
        solved: OSQP reported solved (or solved inaccurate); False means the previous plan's next input
            was reused.
        iterations: ADMM iterations of this solve.
    """

    steer_front_rad: float
    steer_rear_rad: float
    accel_mps2: float
    solved: bool
    iterations: int


def error_model(
    c: CoupledMpcConfig, lf_m: float, lr_m: float, vx_mps: float, all_wheel: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous lateral matrices (A 4x4, B 4, C 4) of eqs. (4)-(5) at speed ``vx_mps``.

    Rajamani's signs (the paper prints C_f l_f + C_r l_r where its source has C_f l_f - C_r l_r in
    A[1, 3] and C[1]). With all-wheel steer the rear wheels take -delta, adding -C_r / m and
    +C_r l_r / I_z to B.
    """
    m, iz, cf, cr = c.mass_kg, c.yaw_inertia_kgm2, c.cornering_front_npr, c.cornering_rear_npr
    v = vx_mps
    a = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [0.0, -(cf + cr) / (m * v), (cf + cr) / m, -(cf * lf_m - cr * lr_m) / (m * v)],
            [0.0, 0.0, 0.0, 1.0],
            [
                0.0,
                -(cf * lf_m - cr * lr_m) / (iz * v),
                (cf * lf_m - cr * lr_m) / iz,
                -(cf * lf_m**2 + cr * lr_m**2) / (iz * v),
            ],
        ]
    )
    if all_wheel:
        b = np.array([0.0, (cf - cr) / m, 0.0, (cf * lf_m + cr * lr_m) / iz])
    else:
        b = np.array([0.0, cf / m, 0.0, cf * lf_m / iz])
    cvec = np.array(
        [0.0, -(cf * lf_m - cr * lr_m) / (m * v) - v, 0.0, -(cf * lf_m**2 + cr * lr_m**2) / (iz * v)]
    )
    return a, b, cvec


def steady_state(
    a: np.ndarray, b: np.ndarray, cvec: np.ndarray, yaw_rate_radps: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(e_psi, delta) holding e_lat = de_lat = de_psi = 0 at each target yaw rate (M,), from rows 1 and 3."""
    m2 = np.array([[a[1, 2], b[1]], [a[3, 2], b[3]]])
    sol = np.linalg.solve(m2, -np.vstack([cvec[1] * yaw_rate_radps, cvec[3] * yaw_rate_radps]))
    return sol[0], sol[1]


class SnowLionMpcController(NoSpeedLaw):
    """Coupled lateral/longitudinal MPC; a lateral controller whose solve also yields the acceleration.

    ``step`` is the lateral-controller interface (wheel angles); the acceleration of the same solve is
    kept in ``last_command``. The speed reference comes from ``set_speed_reference`` (the longitudinal
    planner's); without one the MPC holds the current speed. ``step_coupled`` takes both at once.
    """

    def __init__(self, geometry: VehicleGeometry, config: CoupledMpcConfig | None = None) -> None:
        self.geometry = geometry
        self.config = c = config or CoupledMpcConfig()
        lr = geometry.wheelbase_m / 2.0 if c.cg_from_rear_axle_m is None else c.cg_from_rear_axle_m
        if not 0.0 < lr < geometry.wheelbase_m:
            raise ConfigError(
                f"CoupledMpcConfig.cg_from_rear_axle_m: expected in (0, {geometry.wheelbase_m}) m, got {lr}"
            )
        self.lr_m, self.lf_m = lr, geometry.wheelbase_m - lr
        self.accel_min_mps2 = -geometry.comfort_decel_mps2 if c.accel_min_mps2 is None else c.accel_min_mps2
        self.accel_max_mps2 = geometry.max_accel_mps2 if c.accel_max_mps2 is None else c.accel_max_mps2
        self._tracker = PathTracker()
        self._v_ref: float | None = None
        self._a_ref = 0.0
        self._last = (0.0, 0.0)  # last (front, rear) wheel angles commanded
        self._prev_z: np.ndarray | None = None
        self.solver_failures = 0
        self.last_command: MpcCommand | None = None
        self._build()

    def path_lead_m(self, rear_steer: bool = True) -> float:
        """The centre of gravity, where the error model is measured, ahead of the planned point (the rear
        axle; the centre of the wheelbase with all-wheel steer): the stack feeds the CG's own path."""
        g = self.geometry
        return self.lr_m - (g.wheelbase_m / 2.0 if g.all_wheel_steer and rear_steer else 0.0)

    # ---- QP structure (built once) -------------------------------------------------------------
    def _build(self) -> None:
        c, n = self.config, self.config.horizon_steps
        nxv = NX * n
        self._nz = nz = nxv + NU * n
        q_diag = 1.0 / np.square(
            [
                c.accept_lateral_m,
                c.accept_lateral_rate_mps,
                c.accept_heading_rad,
                c.accept_heading_rate_radps,
                c.accept_lon_m,
                c.accept_speed_mps,
            ]
        )
        r_diag = 1.0 / np.square([c.accept_steer_rad, c.accept_accel_mps2])
        self._rd = 1.0 / c.accept_steer_step_rad**2
        self._q_diag, self._r_diag = q_diag, r_diag
        # Steering-step penalty: sum (delta_k - delta_{k-1})^2 over k >= 1 (k = 0 against the last command
        # enters the linear term).
        di = nxv + NU * np.arange(n)
        diff = sp.coo_matrix(
            (
                np.r_[np.ones(n - 1), -np.ones(n - 1)],
                (np.r_[np.arange(n - 1), np.arange(n - 1)], np.r_[di[1:], di[:-1]]),
            ),
            shape=(n - 1, nz),
        )
        h = sp.diags(np.r_[np.tile(q_diag, n), np.tile(r_diag, n)]) + self._rd * (diff.T @ diff)
        first = np.zeros(nz)
        first[di[0]] = self._rd
        h = h + sp.diags(first)
        self._p = sp.triu(2.0 * h, format="csc")

        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        # Entries are numbered ("slots") in the order listed here; per call the values are written in
        # slot order and permuted into OSQP's CSC order (``_perm``), so the pattern never changes.
        # (1) dynamics: x_{k+1} - Ad x_k - Bd u_k = w_k  (rows 6k .. 6k+5)
        k = np.arange(n)
        rows.append(np.repeat(NX * k, NX) + np.tile(np.arange(NX), n))
        cols.append(rows[-1].copy())
        ad_r, ad_c = self._ad_pattern()
        for kk in range(1, n):
            rows.append(NX * kk + ad_r)
            cols.append(NX * (kk - 1) + ad_c)
        bd_r = np.array([0, 1, 2, 3, 4, 5])
        bd_c = np.array([0, 0, 0, 0, 1, 1])
        for kk in range(n):
            rows.append(NX * kk + bd_r)
            cols.append(nxv + NU * kk + bd_c)
        self._n_ad, self._n_bd = len(ad_r), len(bd_r)
        # (2) input bounds
        r0 = nxv
        rows.append(r0 + np.arange(NU * n))
        cols.append(nxv + np.arange(NU * n))
        # (3) steering steps: delta_0 (against the last command, in the bounds) and delta_k - delta_{k-1}
        r1 = r0 + NU * n
        rows += [r1 + np.arange(n), r1 + np.arange(1, n)]
        cols += [di, di[:-1]]
        self._m = r1 + n
        all_rows, all_cols = np.concatenate(rows), np.concatenate(cols)
        slots = np.arange(len(all_rows), dtype=np.float64) + 1.0
        a = sp.csc_matrix((slots, (all_rows, all_cols)), shape=(self._m, nz))
        self._perm = a.data.astype(np.int64) - 1  # CSC position -> slot
        # Slot values: the constant ones written here once, Ad and Bd per call (``_values``).
        self._slot = np.ones(len(all_rows))
        self._slot[-(n - 1) :] = -1.0
        self._ad_r, self._ad_c = ad_r, ad_c
        # Bounds: the input rows are constant; dynamics and steering-step rows are written per call.
        self._lo = np.empty(self._m)
        self._hi = np.empty(self._m)
        self._lo[r0:r1] = np.tile([-self.geometry.max_steer_rad, self.accel_min_mps2], n)
        self._hi[r0:r1] = np.tile([self.geometry.max_steer_rad, self.accel_max_mps2], n)
        self._r1 = r1
        self._q = np.zeros(nz)
        self._a_template = a
        self._solver: osqp.OSQP | None = None

    @staticmethod
    def _ad_pattern() -> tuple[np.ndarray, np.ndarray]:
        """Pattern of Ad: the 4x4 lateral block (column 0 is e_0 always: e_lat feeds nothing) and the 2x2
        longitudinal block. Entries that vanish only for some parameters stay in it as explicit zeros."""
        lat_r, lat_c = np.divmod(np.arange(16), 4)
        keep = (lat_c > 0) | (lat_r == 0)
        return np.r_[lat_r[keep], 4, 4, 5, 5], np.r_[lat_c[keep], 4, 5, 4, 5]

    def _values(self, ad: np.ndarray, bd: np.ndarray) -> np.ndarray:
        """The constraint matrix's numeric values in OSQP's (CSC) order for this Ad and Bd."""
        n, nxv = self.config.horizon_steps, NX * self.config.horizon_steps
        slot = self._slot
        ad_end = nxv + (n - 1) * self._n_ad
        slot[nxv:ad_end].reshape(n - 1, self._n_ad)[:] = -ad[self._ad_r, self._ad_c]
        bd_block = slot[ad_end : ad_end + n * self._n_bd].reshape(n, self._n_bd)
        bd_block[:, :4] = -bd[:4, 0]
        bd_block[:, 4:] = -bd[4:, 1]
        return slot[self._perm]

    # ---- per call ------------------------------------------------------------------------------
    def set_speed_reference(self, speed_mps: float | None, accel_mps2: float = 0.0) -> None:
        """The speed (and its rate) to track from the next step on; None holds the current speed."""
        self._v_ref = speed_mps
        self._a_ref = accel_mps2

    def discretise(
        self, vx_mps: float, all_wheel: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Exact zero-order hold: Ad (6, 6), Bd (6, 2), Ed (6, 2) (for [psi_dot_tar, a_ref]) and the
        continuous lateral (A, B, C)."""
        c = self.config
        a, b, cvec = error_model(c, self.lf_m, self.lr_m, vx_mps, all_wheel)
        aug = np.zeros((6, 6))
        aug[:4, :4], aug[:4, 4], aug[:4, 5] = a, b, cvec
        phi = scipy.linalg.expm(aug * c.step_s)
        dt = c.step_s
        ad = np.zeros((NX, NX))
        bd = np.zeros((NX, NU))
        ed = np.zeros((NX, 2))
        ad[:4, :4], bd[:4, 0], ed[:4, 0] = phi[:4, :4], phi[:4, 4], phi[:4, 5]
        ad[4:, 4:] = [[1.0, dt], [0.0, 1.0]]
        bd[4:, 1] = [-0.5 * dt * dt, -dt]
        ed[4:, 1] = [0.5 * dt * dt, dt]
        return ad, bd, ed, (a, b, cvec)

    def _initial_state(
        self, pose: SE2, speed_mps: float, path: Polyline, v_ref: float
    ) -> tuple[np.ndarray, float]:
        g = self.geometry
        cg = point_ahead(pose, self.lr_m)
        e = self._tracker.errors(path, cg)
        tan_f, tan_r = math.tan(self._last[0]), math.tan(self._last[1])
        # Body slip and yaw rate of the kinematic bicycle under the last command (the interface gives
        # pose and speed only).
        beta = math.atan((self.lr_m * tan_f + self.lf_m * tan_r) / g.wheelbase_m)
        yaw_rate = speed_mps * math.cos(beta) * (tan_f - tan_r) / g.wheelbase_m
        x0 = np.array(
            [
                e.lateral_m,
                speed_mps * math.sin(e.heading_error_rad + beta),
                e.heading_error_rad,
                yaw_rate - speed_mps * e.curvature_1pm,
                0.0,
                v_ref - speed_mps,
            ]
        )
        return x0, e.s_m

    def step_coupled(
        self,
        dt_s: float,
        map_from_base: SE2,
        speed_mps: float,
        path: Polyline,
        speed_ref_mps: float,
        accel_ref_mps2: float = 0.0,
        rear_steer: bool = True,
    ) -> MpcCommand:
        """Solve once and return the first input."""
        check_speed("SnowLionMpcController.step", speed_mps)
        if not math.isfinite(speed_ref_mps):
            raise ConfigError(
                f"SnowLionMpcController: expected a finite speed reference, got {speed_ref_mps}"
            )
        c, g, n = self.config, self.geometry, self.config.horizon_steps
        all_wheel = g.all_wheel_steer and rear_steer
        v_model = max(speed_mps, c.min_model_speed_mps)
        ad, bd, ed, (a, b, cvec) = self.discretise(v_model, all_wheel)
        x0, s0 = self._initial_state(map_from_base, speed_mps, path, speed_ref_mps)
        # Preview: stations along the horizon at the reference speed, their curvature and target yaw rate.
        v_prev = max(speed_ref_mps, speed_mps, c.min_model_speed_mps)
        s = s0 + v_prev * c.step_s * np.arange(n + 1)
        kappa = curvature_profile(path, s)
        psi_dot = v_model * kappa
        e_psi_ss, delta_ss = steady_state(a, b, cvec, psi_dot)
        # Equality right-hand side w_k = Ad x0 (k = 0) + Ed [psi_dot_k, a_ref].
        w = np.outer(psi_dot[:n], ed[:, 0]) + accel_ref_mps2 * ed[:, 1]  # (n, 6)
        w[0] += ad @ x0
        beq = w.ravel()
        step_max = g.max_steer_rate_radps * c.step_s
        last_delta = self._last[0]
        lo, hi, r1 = self._lo, self._hi, self._r1
        lo[: NX * n] = beq
        hi[: NX * n] = beq
        lo[r1], hi[r1] = last_delta - step_max, last_delta + step_max
        lo[r1 + 1 :], hi[r1 + 1 :] = -step_max, step_max
        # Linear term: -2 Q x_ref - 2 R u_ref - 2 rd delta_last (on delta_0).
        q = self._q
        q[: NX * n] = 0.0
        q[2 : NX * n : NX] = -2.0 * self._q_diag[2] * e_psi_ss[1:]
        q[NX * n :: NU] = -2.0 * self._r_diag[0] * delta_ss[:n]
        q[NX * n + 1 :: NU] = -2.0 * self._r_diag[1] * accel_ref_mps2
        q[NX * n] -= 2.0 * self._rd * last_delta
        ax = self._values(ad, bd)
        if self._solver is None:
            self._solver = osqp.OSQP()
            self._solver.setup(
                self._p,
                q,
                sp.csc_matrix(
                    (ax, self._a_template.indices, self._a_template.indptr), shape=self._a_template.shape
                ),
                lo,
                hi,
                eps_abs=c.eps,
                eps_rel=c.eps,
                max_iter=c.max_iter,
                polishing=False,
                warm_starting=True,
                verbose=False,
            )
        else:
            # OSQP warm-starts from its previous primal and dual solution: the control period is a
            # fraction of the prediction step, so the unshifted solution is the closer guess.
            self._solver.update(q=q, l=lo, u=hi, Ax=ax)
        res = self._solver.solve(raise_error=False)
        status = str(res.info.status)
        solved = status in ("solved", "solved inaccurate")
        if solved:
            z = np.asarray(res.x)
            delta, accel = float(z[NX * n]), float(z[NX * n + 1])
            self._prev_z = self._shift(z) if dt_s >= c.step_s else z
        else:
            self.solver_failures += 1
            if self._prev_z is not None:
                # The previous plan's input for now: the same one until a full step has passed.
                delta, accel = float(self._prev_z[NX * n]), float(self._prev_z[NX * n + 1])
                if dt_s >= c.step_s:
                    self._prev_z = self._shift(self._prev_z)
            else:
                delta, accel = last_delta, self.accel_min_mps2
        delta = min(max(delta, -g.max_steer_rad), g.max_steer_rad)
        accel = min(max(accel, self.accel_min_mps2), self.accel_max_mps2)
        rear = -delta if all_wheel else 0.0
        self._last = (delta, rear)
        self.last_command = MpcCommand(
            steer_front_rad=delta,
            steer_rear_rad=rear,
            accel_mps2=accel,
            solved=solved,
            iterations=int(res.info.iter),
        )
        return self.last_command

    def _shift(self, z: np.ndarray) -> np.ndarray:
        """The solution one step later: states and inputs moved forward, the last repeated."""
        n = self.config.horizon_steps
        xs = z[: NX * n].reshape(n, NX)
        us = z[NX * n :].reshape(n, NU)
        return np.concatenate([np.vstack([xs[1:], xs[-1:]]).ravel(), np.vstack([us[1:], us[-1:]]).ravel()])

    def step(
        self, dt_s: float, map_from_base: SE2, speed_mps: float, path: Polyline, rear_steer: bool = True
    ) -> tuple[float, float]:
        """Lateral-controller interface: wheel angles of a coupled solve at the held speed reference."""
        v_ref = speed_mps if self._v_ref is None else self._v_ref
        a_ref = 0.0 if self._v_ref is None else self._a_ref
        cmd = self.step_coupled(dt_s, map_from_base, speed_mps, path, v_ref, a_ref, rear_steer)
        return cmd.steer_front_rad, cmd.steer_rear_rad
