"""Sweeps: many scenarios on a local process pool (default) or a Ray cluster, one table of outcomes.

Every case is written as two TOML files first, its scenario (the world) and its run configuration (the
vehicle), and each worker reads them back, so the files are provably the whole description of what
ran; the same files and seeds give the same rows on either engine. Each outcome is checked against the
configuration the case actually ran with.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import signal
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.perception_mode import PerceptionMode
from lastmile.evaluation.metrics import compute_metrics
from lastmile.recorder.run_log import RunLog
from lastmile.runner.run_config import RunConfig, load_run_config, run_config_to_toml
from lastmile.runner.stop_signals import StopSignals
from lastmile.sim.operator_estop import STANDSTILL_MPS
from lastmile.sim.scenario import load_scenario, scenario_to_toml
from lastmile.sim.suites import FAULT_CHECKS, GENERIC_CHECKS, SuiteCase

ENGINES = ("local", "ray")
ProgressCallback = Callable[[int, int], None]


@dataclass(frozen=True, slots=True, kw_only=True)
class CheckResult:
    ok: bool
    detail: str


def _events(log: RunLog, kind: str, **match: object) -> list[Any]:
    return [e for e in log.events if e.kind == kind and all(e.data.get(k) == v for k, v in match.items())]


def _check_no_collision(log: RunLog, m: dict[str, Any]) -> CheckResult:
    n = m["collisions_total"]
    return CheckResult(ok=n == 0, detail=f"{n} collisions")


def _check_no_collision_at_fault(log: RunLog, m: dict[str, Any]) -> CheckResult:
    n = m["collisions_at_fault"]
    return CheckResult(ok=n == 0, detail=f"{n} at-fault collisions")


def _check_no_takeover(log: RunLog, m: dict[str, Any]) -> CheckResult:
    reasons = sorted({str(e.data.get("reason")) for e in _events(log, "takeover")})
    return CheckResult(ok=m["takeovers"] == 0, detail=f"{m['takeovers']} takeovers {reasons or ''}".strip())


def _check_in_drivable_area(log: RunLog, m: dict[str, Any]) -> CheckResult:
    n = len(_events(log, "rule_violation", rule="drivable_area"))
    return CheckResult(ok=n == 0, detail=f"left the drivable area {n} times")


def _check_no_rule_violation(log: RunLog, m: dict[str, Any]) -> CheckResult:
    rules = sorted({str(e.data.get("rule")) for e in _events(log, "rule_violation")})
    return CheckResult(
        ok=m["rule_violations"] == 0, detail=f"{m['rule_violations']} violations {rules or ''}"
    )


# What the fail-safe must answer each injected fault with (at least this level), and within how long
# of the fault's start: one period of the affected sensor or module plus 100 ms (issue #5).
EXPECTED_RESPONSE: dict[tuple[str, str], tuple[str, int]] = {
    ("dropout", "radar_front"): ("MINIMAL_RISK_MANOEUVRE", 50_000),
    ("dropout", "radar_rear"): ("SPEED_LIMIT", 50_000),
    ("frozen", "radar_front"): ("MINIMAL_RISK_MANOEUVRE", 50_000),
    ("latency_spike", "radar_front"): ("SPEED_LIMIT", 50_000),
    ("out_of_order", "radar_front"): ("SPEED_LIMIT", 50_000),
    ("garbage", "radar_front"): ("MINIMAL_RISK_MANOEUVRE", 50_000),
    ("blind", "radar_front"): ("MINIMAL_RISK_MANOEUVRE", 50_000),
    ("dropout", "gnss"): ("MINIMAL_RISK_MANOEUVRE", 100_000),
    ("nan", "gnss"): ("MINIMAL_RISK_MANOEUVRE", 100_000),
    ("nan", "imu"): ("MINIMAL_RISK_MANOEUVRE", 20_000),
    ("nan", "odom"): ("MINIMAL_RISK_MANOEUVRE", 20_000),
    ("garbage", "odom"): ("MINIMAL_RISK_MANOEUVRE", 20_000),
    ("frozen", "odom"): ("MINIMAL_RISK_MANOEUVRE", 20_000),
    ("gnss_outage", "gnss"): ("SPEED_LIMIT", 100_000),
    ("gnss_multipath", "gnss"): ("SPEED_LIMIT", 100_000),
    ("map_misalignment", "map"): ("SPEED_LIMIT", 100_000),
    ("module_hang", "planning"): ("MINIMAL_RISK_MANOEUVRE", 100_000),
    ("module_raise", "tracking"): ("MINIMAL_RISK_MANOEUVRE", 100_000),
}
LEVELS = ("NONE", "SPEED_LIMIT", "TAKEOVER_REQUEST", "MINIMAL_RISK_MANOEUVRE", "EMERGENCY_STOP")


def fault_response(log: RunLog) -> list[dict[str, Any]]:
    """Per injected fault: when the fail-safe first answered, at what level, and the bound it had."""
    out = []
    safety = [(e.t_s, e.data["level"]) for e in log.events_of("safety")]
    for start in log.events_of("fault_start"):
        kind, target = str(start.data["kind"]), str(start.data["target"])
        expected, period_us = EXPECTED_RESPONSE.get((kind, target), ("MINIMAL_RISK_MANOEUVRE", 100_000))
        bound_s = (period_us + 100_000) / 1e6
        answers = [(t, lvl) for t, lvl in safety if t >= start.t_s - 1e-9 and lvl != "NONE"]
        first = answers[0] if answers else None
        top = max((LEVELS.index(lvl) for t, lvl in answers if t <= start.t_s + 10.0), default=0)
        out.append(
            {
                "fault": f"{kind}:{target}",
                "expected_level": expected,
                "bound_s": round(bound_s, 3),
                "detected_after_s": None if first is None else round(first[0] - start.t_s, 3),
                "first_level": None if first is None else first[1],
                "max_level_10s": LEVELS[top],
                "ok": first is not None
                and first[0] - start.t_s <= bound_s + 1e-9
                and top >= LEVELS.index(expected),
            }
        )
    return out


def _check_fault_answered(log: RunLog, m: dict[str, Any]) -> CheckResult:
    """Every injected fault detected within its bound and answered at (at least) the expected level."""
    responses = fault_response(log)
    if not responses:
        return CheckResult(ok=False, detail="no fault was injected")
    bad = [r for r in responses if not r["ok"]]
    if not bad:
        worst = max(r["detected_after_s"] for r in responses)
        return CheckResult(ok=True, detail=f"answered within {worst:.2f} s")
    r = bad[0]
    if r["detected_after_s"] is None:
        return CheckResult(ok=False, detail=f"{r['fault']} never detected")
    return CheckResult(
        ok=False,
        detail=f"{r['fault']}: {r['first_level']} after {r['detected_after_s']:.2f} s "
        f"(expected {r['expected_level']} within {r['bound_s']:.2f} s; reached {r['max_level_10s']})",
    )


def _check_no_stack_crash(log: RunLog, m: dict[str, Any]) -> CheckResult:
    crashes = _events(log, "stack_crash")
    return CheckResult(ok=not crashes, detail=str(crashes[0].data["error"]) if crashes else "no crash")


# The operator's e-stop: the fail-safe must be at EMERGENCY_STOP within one stack tick plus 100 ms,
# and the shuttle must stop within its maximum-deceleration stopping time plus this margin (actuator lag
# and the brake's build-up), then stay put until the operator releases it.
ESTOP_RESPONSE_BOUND_S = 0.15
ESTOP_STOP_MARGIN_S = 1.0


def _check_estop_honoured(log: RunLog, m: dict[str, Any]) -> CheckResult:
    """The operator's e-stop stops the shuttle from the state it was pressed in, and holds it stopped."""
    presses = log.events_of("operator_estop")
    wanted = str(log.meta.config.get("estop_in_state", ""))
    if not presses:
        return CheckResult(ok=False, detail=f"the stack never reached state {wanted!r}: no e-stop pressed")
    t0 = presses[0].t_s
    # The level in force just after the bound (it may already have been EMERGENCY_STOP for another cause).
    levels = [e for e in log.events_of("safety") if e.t_s <= t0 + ESTOP_RESPONSE_BOUND_S]
    if not levels or levels[-1].data["level"] != "EMERGENCY_STOP":
        return CheckResult(
            ok=False,
            detail=f"no EMERGENCY_STOP within {ESTOP_RESPONSE_BOUND_S:.2f} s of the press at {t0:.1f} s",
        )
    t = log.column("t_s")
    v = log.column("speed_mps")
    after = t >= t0 - 1e-9
    if not after.any():
        return CheckResult(ok=False, detail=f"the run ended at the press ({t0:.1f} s)")
    v0 = float(abs(v[after][0]))
    bound_s = v0 / _max_decel_mps2(log) + ESTOP_STOP_MARGIN_S
    still = after & (np.abs(v) < STANDSTILL_MPS)
    if not still.any():
        return CheckResult(ok=False, detail=f"never stopped after the press at {t0:.1f} s")
    t_stop = float(t[still][0])
    if t_stop - t0 > bound_s:
        return CheckResult(
            ok=False,
            detail=f"stopped {t_stop - t0:.2f} s after the press (bound {bound_s:.2f} s from {v0:.1f} m/s)",
        )
    releases = log.events_of("operator_release")
    t_release = releases[0].t_s if releases else float(t[-1]) + 1.0
    held = (t >= t_stop) & (t < t_release)
    moved = float(np.max(np.abs(v[held]), initial=0.0))
    if moved >= STANDSTILL_MPS:
        return CheckResult(
            ok=False, detail=f"moved at {moved:.2f} m/s before the operator released the e-stop"
        )
    return CheckResult(
        ok=True, detail=f"stopped {t_stop - t0:.2f} s after the press in {wanted} (bound {bound_s:.2f} s)"
    )


def _max_decel_mps2(log: RunLog) -> float:
    """The emergency-stop deceleration of the configuration the run used (recorded in its log)."""
    try:
        return float(log.meta.config["run_config"]["stack"]["safety"]["max_decel_mps2"])
    except (KeyError, TypeError, ValueError):
        raise ConfigError(
            "estop_honoured: expected the run's configuration (run_config.stack.safety.max_decel_mps2) "
            "in its log, got none"
        ) from None


CHECKS: dict[str, Callable[[RunLog, dict[str, Any]], CheckResult]] = {
    "no_stack_crash": _check_no_stack_crash,
    "no_collision": _check_no_collision,
    "no_collision_at_fault": _check_no_collision_at_fault,
    "no_takeover": _check_no_takeover,
    "in_drivable_area": _check_in_drivable_area,
    "no_rule_violation": _check_no_rule_violation,
    "fault_answered": _check_fault_answered,
    "estop_honoured": _check_estop_honoured,
}
"""Outcome checks by name; a suite case lists the ones its outcome must pass."""


SWEEP_CONFIG = RunConfig().with_perception(PerceptionMode.RADAR_TRACKING)
"""Sweeps perceive through the radars by default: four times cheaper than the raw LiDAR chain, and
what a sweep validates (decision, safety, faults) sits behind either."""


def run_case(scenario_path: str, config_path: str, checks: tuple[str, ...], group: str) -> dict[str, Any]:
    """Run one scenario file with one run configuration file and judge it: a row of the sweep table
    (no wall-clock figures in it).

    Black-box recordings go to ``recordings/<scenario name>/`` beside the ``scenarios`` folder.
    """
    # Imported here so that a worker process pays for the loop only when it runs a case.
    from lastmile.runner.closed_loop import run_scenario

    path = Path(scenario_path)
    sweep_dir = path.parent.parent
    scenario = load_scenario(path)
    config = load_run_config(Path(config_path))
    log = run_scenario(
        scenario,
        config,
        black_box_dir=sweep_dir / "recordings" / scenario.name,
        stop=lambda: _WORKER_STOP.requested,
    )
    m = compute_metrics(log)
    results = {name: CHECKS[name](log, m) for name in checks}
    incidents = [
        {
            "t_s": e.t_s,
            "kind": e.kind,
            **{k: v for k, v in e.data.items() if isinstance(v, str | int | float)},
        }
        for e in log.events
        if e.kind in ("collision", "rule_violation", "takeover")
    ]
    return {
        "name": scenario.name,
        "group": group,
        "scenario_file": scenario_path,
        "config_file": config_path,
        "seed": scenario.seed,
        "weather": scenario.weather,
        "perception_mode": str(config.stack.perception),
        "faults": [f"{f.kind}:{f.target}" for f in scenario.faults],
        "passed": all(r.ok for r in results.values()),
        "interrupted": bool(log.timing.get("interrupted")),
        "checks": {k: {"ok": r.ok, "detail": r.detail} for k, r in results.items()},
        "collisions_total": m["collisions_total"],
        "collisions_at_fault": m["collisions_at_fault"],
        "takeovers": m["takeovers"],
        "rule_violations": m["rule_violations"],
        "distance_m": m["distance_m"],
        "incidents": incidents,
        "fault_response": fault_response(log),
        # Relative to the sweep's folder, so that rows compare equal wherever the sweep ran.
        "recording": next(
            (
                str(Path(str(e.data["path"])).relative_to(path.parent.parent))
                for e in log.events_of("recording")
            ),
            None,
        ),
    }


def check_cases(cases: list[SuiteCase]) -> None:
    """Unique names and known checks, before anything runs or is written."""
    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        raise ConfigError("sweep: expected unique scenario names, got duplicates")
    for case in cases:
        unknown = [c for c in case.checks if c not in CHECKS]
        if unknown:
            raise ConfigError(
                f"sweep case {case.name}: unknown check {unknown[0]!r}; expected one of {sorted(CHECKS)}"
            )


def write_cases(
    cases: list[SuiteCase], out_dir: Path, config: RunConfig = SWEEP_CONFIG
) -> list[tuple[SuiteCase, Path, Path]]:
    """Each case's scenario as ``out_dir/scenarios/<name>.toml`` and the run configuration it runs with
    (``config``, with the case's own shuttle speed) as ``out_dir/configs/<name>.toml``. The scenario
    file carries the case's checks, so the folder re-runs with ``sweep --scenarios`` as it was judged."""
    check_cases(cases)
    folder = out_dir / "scenarios"
    configs = out_dir / "configs"
    folder.mkdir(parents=True, exist_ok=True)
    configs.mkdir(parents=True, exist_ok=True)
    written = []
    for case in cases:
        case_config = (
            config if case.cruise_speed_mps is None else config.with_cruise_speed(case.cruise_speed_mps)
        )
        case_config.check_serves(case.scenario)
        path = folder / f"{case.name}.toml"
        path.write_text(scenario_to_toml(dataclasses.replace(case.scenario, checks=case.checks)))
        config_path = configs / f"{case.name}.toml"
        config_path.write_text(run_config_to_toml(case_config))
        written.append((case, path, config_path))
    return written


def generic_cases(scenarios: list[Any], group: str = "generated") -> list[SuiteCase]:
    """Sweep cases for plain scenarios: the checks their files name, else the generic checks, plus the
    fault check where one is injected."""
    return [
        SuiteCase(
            name=s.name,
            scenario=s,
            checks=s.checks or (FAULT_CHECKS if s.faults else GENERIC_CHECKS),
            group=group,
        )
        for s in scenarios
    ]


def run_sweep(
    cases: list[SuiteCase],
    out_dir: Path,
    engine: str = "local",
    workers: int | None = None,
    ray_address: str | None = None,
    progress: ProgressCallback | None = None,
    config: RunConfig = SWEEP_CONFIG,
    stop: Callable[[], bool] | None = None,
) -> dict[str, Any]:
    """Run every case with ``config`` (each case may set its shuttle speed); writes ``summary.json``
    and returns it (rows in case order).

    ``stop()`` turning true (Ctrl-C, SIGTERM: :mod:`lastmile.runner.stop_signals`) ends the sweep: cases
    not started are left out and listed under ``not_run``, running ones stop at their next tick and give
    a row marked ``interrupted`` (judged on the time simulated, never counted as passed).
    """
    if engine not in ENGINES:
        raise ConfigError(f"sweep --engine: expected one of {ENGINES}, got {engine!r}")
    if workers is not None and workers < 1:
        raise ConfigError(f"sweep --workers: expected at least 1 worker process, got {workers}")
    written = write_cases(cases, out_dir, config)
    jobs = [(str(path), str(config_path), case.checks, case.group) for case, path, config_path in written]
    if engine == "local":
        rows = _run_local(jobs, workers, progress, stop)
    else:
        rows = _run_ray(jobs, ray_address, progress)
    summary = summarize(rows)
    ran = {r["name"] for r in rows}
    summary["not_run"] = [case.name for case, _, _ in written if case.name not in ran]
    summary["interrupted"] = bool(summary["not_run"]) or any(r.get("interrupted") for r in rows)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    passed = sum(1 for r in rows if r["passed"] and not r.get("interrupted"))
    return {
        "scenarios": len(rows),
        "passed": passed,
        "failed": len(rows) - passed,
        "collisions_at_fault": sum(r["collisions_at_fault"] for r in rows),
        "collisions_total": sum(r["collisions_total"] for r in rows),
        "perception_modes": sorted({r["perception_mode"] for r in rows}),
        "rows": rows,
    }


def pin_blas_threads() -> None:
    """Ask for one BLAS thread in this process (a process pool's initializer).

    It sets the environment, so it holds for BLAS libraries loaded after it; a forked worker keeps its
    parent's BLAS, which is why callers also set these variables before importing NumPy.
    """
    # One BLAS thread per worker: the loop's small matrices only get slower when threads compete.
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = "1"


_WORKER_STOP = StopSignals()
"""In a sweep's worker process: Ctrl-C (the terminal's, or forwarded) ends the running case early."""

STOP_POLL_S = 0.2
"""How often the sweep's parent looks for a stop request while it waits for cases."""


def _init_worker() -> None:
    pin_blas_threads()
    _WORKER_STOP.__enter__()


def _run_local(
    jobs: list[tuple[str, str, tuple[str, ...], str]],
    workers: int | None,
    progress: ProgressCallback | None,
    stop: Callable[[], bool] | None = None,
) -> list[dict[str, Any]]:
    workers = workers or os.cpu_count() or 1
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    with ProcessPoolExecutor(max_workers=workers, initializer=_init_worker) as pool:
        futures = {pool.submit(run_case, *job): i for i, job in enumerate(jobs)}
        pending = set(futures)
        done = 0
        stopping = False
        while pending:
            finished, pending = wait(pending, timeout=STOP_POLL_S, return_when=FIRST_COMPLETED)
            for future in finished:
                if future.cancelled():
                    continue
                rows[futures[future]] = future.result()
                done += 1
                if progress is not None:
                    progress(done, len(jobs))
            if not stopping and stop is not None and stop():
                stopping = True
                for future in pending:
                    future.cancel()
                _interrupt_workers(pool)
    return [r for r in rows if r is not None]


def _interrupt_workers(pool: ProcessPoolExecutor) -> None:
    """Ask each worker to end its case at the next tick (a terminal's Ctrl-C reached them already; a
    SIGTERM to the sweep did not). The executor keeps its processes in a private mapping."""
    processes: dict[int, Any] = getattr(pool, "_processes", None) or {}
    for pid in list(processes):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGINT)


def _run_ray(
    jobs: list[tuple[str, str, tuple[str, ...], str]], address: str | None, progress: ProgressCallback | None
) -> list[dict[str, Any]]:
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "sweep --engine ray: expected the optional extra (pip install 'lastmile[ray]'), got no ray"
        ) from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(
            address=address,
            include_dashboard=False,
            log_to_driver=False,
            runtime_env={"env_vars": {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}},
        )
    try:
        remote = ray.remote(run_case)
        refs = [remote.remote(*job) for job in jobs]
        index = {ref: i for i, ref in enumerate(refs)}
        rows: list[dict[str, Any] | None] = [None] * len(jobs)
        pending = list(refs)
        done = 0
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                rows[index[ref]] = ray.get(ref)
                done += 1
                if progress is not None:
                    progress(done, len(jobs))
        return [r for r in rows if r is not None]
    finally:
        if started_here:
            ray.shutdown()
