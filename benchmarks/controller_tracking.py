"""Lateral controllers side by side on the same reference paths: tracking error, comfort, compute time.

Run: python benchmarks/controller_tracking.py [--front-steer] [--json out.json] [--paths figure8 uturn campus]

Every registered lateral controller drives the simulator's kinematic bicycle (``sim.vehicle_model``:
first-order steering and acceleration lags, steering-rate limit) along three reference paths:
  * figure8: a lemniscate of Bernoulli (a = 30 m, tightest radius 10 m) at 3 m/s (GEM's figure-8 test:
    12 cm peak cross-track error);
  * campus: the built-in campus map's service loop at service speed (20 km/h, lowered to
    sqrt(1 m/s^2 / kappa) in curves and reached at 0.8 m/s^2), one lap;
  * uturn: 30 m straight, a 5 m radius U-turn, 40 m straight, at sqrt(1 m/s^2 * 5 m) = 2.24 m/s
    (aUToronto: 40 cm peak on high-curvature turns and a tight U-turn).
A stand-in planner hands each controller a fresh local path every 100 ms (the reference from 10 m behind
to 60 m ahead of the vehicle, 0.5 m vertices), as the stack's planner does at 10 Hz; control runs at
50 Hz, the vehicle at 100 Hz. The speed loop is the stack's (WATonoBus eq. 1 law) for every controller
except Snow Lion's MPC, whose own acceleration drives the car (it gets the same speed reference).
Cross-track and heading errors are those of the wheelbase's centre against the reference (with
front steer that point sits off the path by geometry for any controller that tracks an axle; "own-ref"
is the peak at the point each controller itself keeps on the path: front axle for Stanley and MPS, the
centre for the MPC and with all-wheel steer, else the rear axle); lateral
acceleration comes from its course rate, its jerk from 0.1 s window means as the evaluation's. Compute
time is the thread CPU time (the machine is shared) of the controller's ``step`` call (the MPC's
includes the discretisation, the matrix values and the OSQP solve); the reference operation beside it
is one projection of a point onto the local path, which every controller does at least once.
The MPC's cached, warm-started OSQP workspace is also compared with what a user would otherwise write:
a fresh ``osqp.OSQP().setup(...)`` per solve on the same problems (ratio). One core, BLAS one thread.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import osqp
import scipy.sparse as sp
from rich.console import Console
from rich.table import Table

from lastmile.control.coupled_mpc import SnowLionMpcController
from lastmile.control.lateral import LateralControllerName, make_lateral_controller
from lastmile.control.longitudinal import WatonobusLongitudinalController
from lastmile.control.path_errors import curvature_profile, path_heading_rad
from lastmile.core.geometry import SE2, wrap_angle_rad
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry
from lastmile.hdmap.loader import load_campus_map
from lastmile.hdmap.routing import campus_shuttle_loop, route_polyline
from lastmile.sim.vehicle_model import ActuatorDynamics, KinematicBicycle, VehicleState

CONTROL_DT_S = 0.02
SIM_SUBSTEPS = 2
PLAN_EVERY = 5  # control steps per local path (10 Hz)
A_LAT_MPS2 = 1.0  # the stack's curvature speed limit (LongitudinalConfig.max_lateral_accel_mps2)
A_NOM_MPS2 = 0.8
TARGETS = {"figure8": (0.12, 0.05, "GEM 12 cm peak"), "uturn": (0.40, 0.20, "aUToronto 40 cm peak")}


@dataclass
class Reference:
    """A reference path and its speed profile."""

    name: str
    line: Polyline
    speed_cap_mps: float
    laps: float = 1.0
    v_profile: np.ndarray = field(default_factory=lambda: np.zeros(0))
    s_grid: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        # Curvature limit, then the comfortable-braking envelope behind every slow point (backward pass).
        self.s_grid = np.arange(0.0, self.line.length_m, 0.5)
        kappa = np.abs(curvature_profile(self.line, self.s_grid))
        v = np.minimum(self.speed_cap_mps, np.sqrt(A_LAT_MPS2 / np.maximum(kappa, 1e-6)))
        for _ in range(2 if self.line.closed else 1):
            for i in range(len(v) - 2, -1, -1) if not self.line.closed else range(len(v) - 1, -1, -1):
                nxt = v[(i + 1) % len(v)]
                v[i] = min(v[i], math.sqrt(nxt * nxt + 2.0 * A_NOM_MPS2 * 0.5))
        self.v_profile = v

    def speed_at(self, s_m: float) -> float:
        s = s_m % self.line.length_m if self.line.closed else min(max(s_m, 0.0), self.s_grid[-1])
        return float(np.interp(s, self.s_grid, self.v_profile))


def figure8() -> Reference:
    t = np.linspace(0.0, 2.0 * np.pi, 1200, endpoint=False)
    a = 30.0
    den = 1.0 + np.sin(t) ** 2
    xy = np.c_[a * np.cos(t) / den, a * np.sin(t) * np.cos(t) / den]
    return Reference("figure8", Polyline(xy, closed=True), 3.0)


def uturn() -> Reference:
    r = 5.0
    straight = np.c_[np.arange(0.0, 30.0, 0.5), np.zeros(60)]
    ang = np.linspace(-np.pi / 2, np.pi / 2, 64)
    arc = np.c_[30.0 + r * np.cos(ang), r + r * np.sin(ang)]
    back = np.c_[np.arange(29.5, -10.0, -0.5), np.full(79, 2 * r)]
    return Reference("uturn", Polyline(np.vstack([straight, arc[1:-1], back])), math.sqrt(A_LAT_MPS2 * r))


def campus() -> Reference:
    hd = load_campus_map()
    line = route_polyline(hd, campus_shuttle_loop(hd), closed=True)
    return Reference("campus", line, VehicleGeometry().max_speed_mps)


@dataclass
class RunResult:
    xte_m: list[float] = field(default_factory=list)
    xte_own_m: list[float] = field(default_factory=list)
    heading_rad: list[float] = field(default_factory=list)
    lat_acc_mps2: list[float] = field(default_factory=list)
    call_ns: list[int] = field(default_factory=list)
    ref_ns: list[int] = field(default_factory=list)
    fresh_ns: list[int] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)

    def summary(self) -> dict[str, float]:
        xte = np.abs(self.xte_m)
        head = np.abs(self.heading_rad)
        acc = np.asarray(self.lat_acc_mps2)
        # As the evaluation measures jerk: the acceleration averaged over 0.1 s windows, differentiated.
        per = round(0.1 / CONTROL_DT_S)
        windows = acc[: len(acc) // per * per].reshape(-1, per).mean(axis=1)
        jerk = np.diff(windows) / 0.1
        return {
            "xte_peak_m": float(xte.max()),
            "xte_mean_m": float(xte.mean()),
            "xte_own_ref_peak_m": float(np.abs(self.xte_own_m).max()),
            "heading_peak_rad": float(head.max()),
            "heading_mean_rad": float(head.mean()),
            "lat_accel_peak_mps2": float(np.abs(acc).max()),
            "lat_jerk_peak_mps3": float(np.abs(jerk).max()),
            "lat_jerk_p95_mps3": float(np.percentile(np.abs(jerk), 95)),
            "call_p50_us": statistics.median(self.call_ns) / 1e3,
            "call_p95_us": float(np.percentile(self.call_ns, 95)) / 1e3,
            "ref_project_p50_us": statistics.median(self.ref_ns) / 1e3,
        }


def _mid(s: VehicleState, g: VehicleGeometry) -> SE2:
    return SE2(s.x_m, s.y_m, s.yaw_rad).compose(SE2(g.wheelbase_m / 2.0, 0.0, 0.0))


def own_reference_m(name: LateralControllerName, g: VehicleGeometry) -> float:
    """Distance ahead of the rear axle of the point the controller itself puts on the path."""
    if name in (LateralControllerName.STANLEY, LateralControllerName.MODEL_PREDICTIVE_STANLEY):
        return g.wheelbase_m  # the front axle
    if name == LateralControllerName.SNOW_LION_MPC or g.all_wheel_steer:
        return g.wheelbase_m / 2.0  # centre of gravity / the point all-wheel steer keeps on the path
    return 0.0  # the rear axle


def drive(ref: Reference, name: LateralControllerName, g: VehicleGeometry, compare_fresh: bool) -> RunResult:
    """One controller along one reference, started on the path at the reference speed."""
    x0, y0, _ = ref.line.point_at(0.0)
    h0 = path_heading_rad(ref.line, 0.0)
    half = g.wheelbase_m / 2.0
    v0 = ref.speed_at(0.0)
    car = KinematicBicycle(
        g,
        ActuatorDynamics(),
        VehicleState(x0 - half * math.cos(h0), y0 - half * math.sin(h0), h0, speed_mps=v0),
    )
    lat = make_lateral_controller(name, g)
    lon = WatonobusLongitudinalController()
    lon.reset(v0)
    out = RunResult()
    s_ref, travelled, s_own = 0.0, 0.0, None
    own = own_reference_m(name, g)
    total = ref.laps * ref.line.length_m - (0.0 if ref.line.closed else 12.0)
    path: Polyline | None = None
    prev_course: float | None = None
    prev_mid = _mid(car.state, g)
    step = 0
    # Thread CPU time: the machine is shared, and wall time would count other processes' slices.
    clock = time.thread_time_ns
    while travelled < total and step < 400_000:
        st = car.state
        mid = _mid(st, g)
        f = ref.line.project(mid.x_m, mid.y_m, hint_s_m=s_ref, window_m=10.0)
        travelled += ref.line.ds_m(s_ref, f.s_m) if step else 0.0
        s_ref = f.s_m
        if step % PLAN_EVERY == 0:
            path = Polyline(ref.line.sub(s_ref - 10.0, s_ref + 60.0, 0.5)) if ref.line.closed else None
            if path is None:
                lo, hi = max(0.0, s_ref - 10.0), min(ref.line.length_m, s_ref + 60.0)
                path = Polyline(ref.line.sub(lo, hi, 0.5))
        assert path is not None
        pose = SE2(st.x_m, st.y_m, st.yaw_rad)
        v_ref = ref.speed_at(s_ref + 1.0)
        t0 = clock()
        path.project(mid.x_m, mid.y_m)
        t1 = clock()
        if isinstance(lat, SnowLionMpcController):
            t1 = clock()
            cmd = lat.step_coupled(CONTROL_DT_S, pose, st.speed_mps, path, v_ref)
            t2 = clock()
            out.iterations.append(cmd.iterations)
            if compare_fresh:
                out.fresh_ns.append(fresh_solve_ns(lat))
            accel, df, dr = cmd.accel_mps2, cmd.steer_front_rad, cmd.steer_rear_rad
        else:
            t1 = clock()
            df, dr = lat.step(CONTROL_DT_S, pose, st.speed_mps, path)
            t2 = clock()
            accel = lon.step(CONTROL_DT_S, st.speed_mps, v_ref, None)
        out.ref_ns.append(t1 - t0)
        out.call_ns.append(t2 - t1)
        for _ in range(SIM_SUBSTEPS):
            car.step(CONTROL_DT_S / SIM_SUBSTEPS, accel, df, dr, False)
        new_mid = _mid(car.state, g)
        dx, dy = new_mid.x_m - prev_mid.x_m, new_mid.y_m - prev_mid.y_m
        speed = math.hypot(dx, dy) / CONTROL_DT_S
        course = math.atan2(dy, dx) if speed > 0.05 else (prev_course or new_mid.yaw_rad)
        if prev_course is not None and step > 10:
            out.lat_acc_mps2.append(speed * wrap_angle_rad(course - prev_course) / CONTROL_DT_S)
            out.xte_m.append(f.d_m)
            op = SE2(st.x_m, st.y_m, st.yaw_rad).compose(SE2(own, 0.0, 0.0))
            hint = s_own if s_own is not None else s_ref
            fo = ref.line.project(op.x_m, op.y_m, hint_s_m=hint, window_m=10.0)
            s_own = fo.s_m
            out.xte_own_m.append(fo.d_m)
            out.heading_rad.append(wrap_angle_rad(mid.yaw_rad - path_heading_rad(ref.line, f.s_m)))
        prev_course, prev_mid = course, new_mid
        step += 1
    return out


def fresh_solve_ns(mpc: SnowLionMpcController) -> int:
    """Time (ns) of what a user would otherwise write: a fresh OSQP setup and solve of the QP the cached
    MPC has just solved (same matrices, bounds and settings; building the matrices is not counted)."""
    solver = mpc._solver
    assert solver is not None
    cache = solver._derivative_cache
    p, a = cache["P"], cache["A"]
    c = mpc.config
    t0 = time.thread_time_ns()
    fresh = osqp.OSQP()
    fresh.setup(
        sp.csc_matrix((p.data, p.indices, p.indptr), shape=p.shape),
        cache["q"],
        sp.csc_matrix((a.data, a.indices, a.indptr), shape=a.shape),
        cache["l"],
        cache["u"],
        eps_abs=c.eps,
        eps_rel=c.eps,
        max_iter=c.max_iter,
        polishing=False,
        verbose=False,
    )
    fresh.solve(raise_error=False)
    return time.thread_time_ns() - t0


def mpc_summary(run: RunResult, horizon_steps: int) -> dict[str, float]:
    """The MPC's own call (discretisation, values, update, solve) against a fresh setup per solve."""
    cached = run.call_ns[1:]
    c50 = statistics.median(cached)
    out = {
        "horizon_steps": float(horizon_steps),
        "calls": float(len(cached)),
        "cached_p50_us": c50 / 1e3,
        "cached_p95_us": float(np.percentile(cached, 95)) / 1e3,
        "iterations_p50": float(statistics.median(run.iterations)),
    }
    if run.fresh_ns:
        f50 = statistics.median(run.fresh_ns[1:])
        out |= {"fresh_setup_solve_p50_us": f50 / 1e3, "fresh_over_cached": f50 / c50}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--front-steer", action="store_true", help="front-wheel steer only (default: all-wheel)")
    ap.add_argument(
        "--paths", nargs="+", default=["figure8", "uturn", "campus"], choices=["figure8", "uturn", "campus"]
    )
    ap.add_argument("--controllers", nargs="+", default=[n.value for n in LateralControllerName])
    ap.add_argument(
        "--json", type=Path, default=Path(__file__).with_name("results") / "controller_tracking.json"
    )
    args = ap.parse_args()
    g = VehicleGeometry(all_wheel_steer=not args.front_steer)
    load_before = os.getloadavg()
    cpu0 = time.process_time()
    builders: dict[str, Callable[[], Reference]] = {"figure8": figure8, "uturn": uturn, "campus": campus}
    results: dict[str, dict[str, dict[str, float]]] = {}
    solver: dict[str, float] = {}
    console = Console(width=200)
    for pname in args.paths:
        ref = builders[pname]()
        results[pname] = {}
        for cname in args.controllers:
            name = LateralControllerName(cname)
            mpc = name == LateralControllerName.SNOW_LION_MPC
            run = drive(ref, name, g, compare_fresh=mpc and pname == "figure8")
            results[pname][cname] = run.summary()
            if mpc and (pname == "figure8" or not solver):
                solver = mpc_summary(run, SnowLionMpcController(g).config.horizon_steps) | {"path": pname}
        base = results[pname].get(LateralControllerName.HEADING_PID.value)
        table = Table(
            title=f"{pname}: {ref.line.length_m:.0f} m, speed cap {ref.speed_cap_mps:.2f} m/s, "
            f"{'all-wheel' if g.all_wheel_steer else 'front'} steer"
        )
        for col in (
            "controller",
            "xte peak cm",
            "xte mean cm",
            "vs heading_pid",
            "own-ref peak cm",
            "head peak deg",
            "head mean deg",
            "a_lat peak",
            "j_lat peak",
            "j_lat p95",
            "call p50 us",
            "call p95 us",
            "project p50 us",
        ):
            table.add_column(col, justify="right")
        for cname, r in results[pname].items():
            ratio = f"{r['xte_peak_m'] / base['xte_peak_m']:.2f}x" if base else "-"
            table.add_row(
                cname,
                f"{100 * r['xte_peak_m']:.1f}",
                f"{100 * r['xte_mean_m']:.1f}",
                ratio,
                f"{100 * r['xte_own_ref_peak_m']:.1f}",
                f"{math.degrees(r['heading_peak_rad']):.2f}",
                f"{math.degrees(r['heading_mean_rad']):.2f}",
                f"{r['lat_accel_peak_mps2']:.2f}",
                f"{r['lat_jerk_peak_mps3']:.2f}",
                f"{r['lat_jerk_p95_mps3']:.2f}",
                f"{r['call_p50_us']:.0f}",
                f"{r['call_p95_us']:.0f}",
                f"{r['ref_project_p50_us']:.1f}",
            )
        console.print(table)
        if pname in TARGETS:
            limit, aim, what = TARGETS[pname]
            best = min(results[pname].items(), key=lambda kv: kv[1]["xte_peak_m"])
            console.print(
                f"  target ({what}): beat {100 * limit:.0f} cm, aim {100 * aim:.0f} cm; best {best[0]} "
                f"{100 * best[1]['xte_peak_m']:.1f} cm; beaten by "
                f"{[k for k, v in results[pname].items() if v['xte_peak_m'] < limit]}"
            )
    if solver:
        fresh = (
            f"; a fresh OSQP setup + solve of the same QP {solver['fresh_setup_solve_p50_us']:.0f} us "
            f"({solver['fresh_over_cached']:.2f}x the cached call)"
            if "fresh_over_cached" in solver
            else ""
        )
        console.print(
            f"MPC N={solver['horizon_steps']:.0f} on {solver['path']} ({solver['calls']:.0f} calls): "
            "CPU per call "
            f"(discretisation + matrix values + warm-started solve) {solver['cached_p50_us']:.0f} us median, "
            f"p95 {solver['cached_p95_us']:.0f} us, {solver['iterations_p50']:.0f} ADMM iterations median"
            f"{fresh}; target < 2000 us median"
        )
    load_after = os.getloadavg()
    console.print(
        f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (2 cores); "
        f"CPU {time.process_time() - cpu0:.1f} s"
    )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "vehicle": "all_wheel_steer" if g.all_wheel_steer else "front_steer",
                "results": results,
                "mpc_solver": solver,
                "targets_cm": {k: {"beat": 100 * v[0], "aim": 100 * v[1]} for k, v in TARGETS.items()},
                "load_avg_before_after": [load_before[0], load_after[0]],
            },
            indent=2,
        )
    )
    console.print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
