"""The sweep's report: a pass/fail table per test-plan group and per scenario, and every incident.

Reads the sweep summary (the dict ``summary.json`` holds); it never runs anything.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def write_sweep_report(summary: dict[str, Any], out_dir: Path, title: str) -> Path:
    """Write ``out_dir/report.md`` (and ``outcomes.png``); returns the report's path."""
    rows = summary["rows"]
    groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        groups[row["group"]].append(row)
    lines = [
        f"# {title}",
        "",
        f"{summary['scenarios']} scenarios: **{summary['passed']} passed, {summary['failed']} failed**; "
        f"{summary['collisions_total']} collisions, of which {summary['collisions_at_fault']} at fault.",
        "",
        f"Perception mode: {', '.join(summary.get('perception_modes', [])) or 'unknown'}.",
        "",
        *_interruption(summary),
        "![outcomes per group](outcomes.png)",
        "",
        *_group_table(groups),
        *_scenario_table(rows),
        *_fault_table(rows),
        *_incident_table(rows),
    ]
    path = out_dir / "report.md"
    path.write_text("\n".join(lines) + "\n")
    _plot(groups, out_dir / "outcomes.png")
    return path


def _group_table(groups: dict[str, list[dict[str, Any]]]) -> list[str]:
    lines = ["## By group", "", "| group | scenarios | passed | failed |", "|---|---:|---:|---:|"]
    for name, members in groups.items():
        ok = sum(1 for r in members if r["passed"] and not r.get("interrupted"))
        lines.append(f"| {name} | {len(members)} | {ok} | {len(members) - ok} |")
    return lines


def _scenario_table(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "",
        "## Scenarios",
        "",
        "| scenario | weather | faults | result | failed checks |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        failed = "; ".join(f"{k}: {v['detail']}" for k, v in r["checks"].items() if not v["ok"])
        faults = ", ".join(r["faults"]) or "-"
        verdict = "interrupted" if r.get("interrupted") else "PASS" if r["passed"] else "**FAIL**"
        lines.append(f"| `{r['name']}` | {r['weather']} | {faults} | {verdict} | {failed or '-'} |")
    return lines


def _incident_table(rows: list[dict[str, Any]]) -> list[str]:
    lines = ["", "## Collisions and rule violations", ""]
    incidents = [(r, i) for r in rows for i in r["incidents"] if i["kind"] in ("collision", "rule_violation")]
    if not incidents:
        return [*lines, "None."]
    lines += [
        "| scenario file | t (s) | what | at fault | black-box recording |",
        "|---|---:|---|---|---|",
    ]
    for r, i in incidents:
        what = i["kind"] if i["kind"] == "collision" else f"rule violation: {i.get('rule', '')}"
        if i["kind"] == "collision":
            what += f" with {i.get('agent_class', '?')} {i.get('agent_id', '')}"
            fault = "yes" if i.get("at_fault") else "no"
        else:
            fault = "yes"  # breaking a rule is the shuttle's doing
        recording = r["recording"] or "none"
        lines.append(f"| `{r['scenario_file']}` | {i['t_s']:.2f} | {what} | {fault} | {recording} |")
    return lines


def _fault_table(rows: list[dict[str, Any]]) -> list[str]:
    """Per injected fault kind: how often it was detected within its bound and at what level."""
    by_fault: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        for f in r.get("fault_response", []):
            by_fault[f["fault"]].append(f)
    if not by_fault:
        return []
    lines = [
        "",
        "## Fault response",
        "",
        "Detection time is from the fault's start to the fail-safe's first answer; the bound is one period",
        "of the affected sensor or module plus 100 ms; the level is the highest within 10 s.",
        "",
        "| fault | injected | answered in bound | detection median / max (s) | bound (s) | expected | "
        "reached |",
        "|---|---:|---:|---|---:|---|---|",
    ]
    for fault, items in sorted(by_fault.items()):
        times = sorted(f["detected_after_s"] for f in items if f["detected_after_s"] is not None)
        timing = f"{times[len(times) // 2]:.2f} / {times[-1]:.2f}" if times else "never detected"
        if len(times) < len(items):
            timing += f" ({len(items) - len(times)} never)"
        reached = ", ".join(sorted({str(f["max_level_10s"]) for f in items}))
        ok = sum(1 for f in items if f["ok"])
        lines.append(
            f"| {fault} | {len(items)} | {ok} | {timing} | {items[0]['bound_s']:.2f} | "
            f"{items[0]['expected_level']} | {reached} |"
        )
    return lines


def _plot(groups: dict[str, list[dict[str, Any]]], path: Path) -> None:
    names = list(groups)
    passed = [sum(1 for r in groups[n] if r["passed"]) for n in names]
    failed = [len(groups[n]) - p for n, p in zip(names, passed, strict=True)]
    fig, ax = plt.subplots(figsize=(8, 0.6 * len(names) + 1.5))
    ax.barh(names, passed, color="tab:green", label="passed")
    ax.barh(names, failed, left=passed, color="tab:red", label="failed")
    ax.set_xlabel("scenarios")
    ax.legend(loc="lower right")
    ax.invert_yaxis()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _interruption(summary: dict[str, Any]) -> list[str]:
    """A warning paragraph when the sweep was stopped before every case had run to its end."""
    if not summary.get("interrupted"):
        return []
    cut = [r["name"] for r in summary["rows"] if r.get("interrupted")]
    not_run = summary.get("not_run", [])
    return [
        f"**Interrupted** (Ctrl-C or SIGTERM): {len(cut)} scenarios stopped early and judged on the time "
        f"simulated (never counted as passed), {len(not_run)} not run"
        + (f": {', '.join(f'`{n}`' for n in not_run)}." if not_run else "."),
        "",
    ]
