"""Sweeps: many scenarios on a local process pool (default) or a Ray cluster, one table of outcomes.

Every case is written as a TOML file first and each worker reads it back, so the file is provably the
whole description of what ran; the same files and seeds give the same rows on either engine.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lastmile.core.errors import ConfigError
from lastmile.evaluation.metrics import compute_metrics
from lastmile.recorder.run_log import RunLog
from lastmile.sim.scenario import load_scenario, scenario_to_toml
from lastmile.sim.suites import GENERIC_CHECKS, SuiteCase

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


def _check_fault_answered(log: RunLog, m: dict[str, Any]) -> CheckResult:
    """The injected fault was detected in time and answered by the expected fail-safe level.

    The stack reports what its safety module decided as ``safety`` events; the sweep compares them
    with the injected faults (``fault_start`` events) in :mod:`lastmile.evaluation.fault_response`.
    """
    faults = _events(log, "fault_start")
    answers = _events(log, "safety")
    if not faults:
        return CheckResult(ok=False, detail="no fault was injected")
    if not answers:
        return CheckResult(ok=False, detail="no safety response logged (no safety monitor in the stack)")
    return CheckResult(ok=True, detail=f"{len(answers)} safety responses")


def _check_no_stack_crash(log: RunLog, m: dict[str, Any]) -> CheckResult:
    crashes = _events(log, "stack_crash")
    return CheckResult(ok=not crashes, detail=str(crashes[0].data["error"]) if crashes else "no crash")


CHECKS: dict[str, Callable[[RunLog, dict[str, Any]], CheckResult]] = {
    "no_stack_crash": _check_no_stack_crash,
    "no_collision": _check_no_collision,
    "no_collision_at_fault": _check_no_collision_at_fault,
    "no_takeover": _check_no_takeover,
    "in_drivable_area": _check_in_drivable_area,
    "no_rule_violation": _check_no_rule_violation,
    "fault_answered": _check_fault_answered,
}
"""Outcome checks by name; a suite case lists the ones its outcome must pass."""


def run_case(scenario_path: str, checks: tuple[str, ...], group: str) -> dict[str, Any]:
    """Run one scenario file and judge it: a row of the sweep table (no wall-clock figures in it)."""
    # Imported here so that a worker process pays for the loop only when it runs a case.
    from lastmile.runner.closed_loop import run_scenario

    scenario = load_scenario(Path(scenario_path))
    log = run_scenario(scenario)
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
        "seed": scenario.seed,
        "weather": scenario.weather,
        "faults": [f"{f.kind}:{f.target}" for f in scenario.faults],
        "passed": all(r.ok for r in results.values()),
        "checks": {k: {"ok": r.ok, "detail": r.detail} for k, r in results.items()},
        "collisions_total": m["collisions_total"],
        "collisions_at_fault": m["collisions_at_fault"],
        "takeovers": m["takeovers"],
        "rule_violations": m["rule_violations"],
        "distance_m": m["distance_m"],
        "incidents": incidents,
        "recording": None,
    }


def write_cases(cases: list[SuiteCase], out_dir: Path) -> list[tuple[SuiteCase, Path]]:
    """Each case's scenario as ``out_dir/scenarios/<name>.toml``."""
    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        raise ConfigError("sweep: expected unique scenario names, got duplicates")
    for case in cases:
        unknown = [c for c in case.checks if c not in CHECKS]
        if unknown:
            raise ConfigError(
                f"sweep case {case.name}: unknown check {unknown[0]!r}; expected one of {sorted(CHECKS)}"
            )
    folder = out_dir / "scenarios"
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for case in cases:
        path = folder / f"{case.name}.toml"
        path.write_text(scenario_to_toml(case.scenario))
        written.append((case, path))
    return written


def generic_cases(scenarios: list[Any], group: str = "generated") -> list[SuiteCase]:
    """Sweep cases for plain scenarios: the generic checks, plus the fault check where one is injected."""
    return [
        SuiteCase(
            name=s.name,
            scenario=s,
            checks=(*GENERIC_CHECKS, "fault_answered") if s.faults else GENERIC_CHECKS,
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
) -> dict[str, Any]:
    """Run every case; writes ``summary.json`` and returns it (rows in case order)."""
    if engine not in ENGINES:
        raise ConfigError(f"sweep --engine: expected one of {ENGINES}, got {engine!r}")
    written = write_cases(cases, out_dir)
    jobs = [(str(path), case.checks, case.group) for case, path in written]
    rows = _run_local(jobs, workers, progress) if engine == "local" else _run_ray(jobs, ray_address, progress)
    summary = summarize(rows)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    passed = sum(1 for r in rows if r["passed"])
    return {
        "scenarios": len(rows),
        "passed": passed,
        "failed": len(rows) - passed,
        "collisions_at_fault": sum(r["collisions_at_fault"] for r in rows),
        "collisions_total": sum(r["collisions_total"] for r in rows),
        "rows": rows,
    }


def _pin_blas() -> None:
    # One BLAS thread per worker: the loop's small matrices only get slower when threads compete.
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = "1"


def _run_local(
    jobs: list[tuple[str, tuple[str, ...], str]], workers: int | None, progress: ProgressCallback | None
) -> list[dict[str, Any]]:
    workers = workers or os.cpu_count() or 1
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    with ProcessPoolExecutor(max_workers=workers, initializer=_pin_blas) as pool:
        futures = {pool.submit(run_case, *job): i for i, job in enumerate(jobs)}
        for done, future in enumerate(as_completed(futures), start=1):
            rows[futures[future]] = future.result()
            if progress is not None:
                progress(done, len(jobs))
    return [r for r in rows if r is not None]


def _run_ray(
    jobs: list[tuple[str, tuple[str, ...], str]], address: str | None, progress: ProgressCallback | None
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
