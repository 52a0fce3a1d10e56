"""The report's tables that explain a run: failed checks with their reasons, the stops one by one, and
events with their real cause (an operator's e-stop, not "stack_request"), encounters merged."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lastmile.core.run_events import EventKind
from lastmile.evaluation import metrics as metrics_mod
from lastmile.evaluation import report_views, run_signals
from lastmile.recorder import run_log

CAUSE_WINDOW_S = 1.0
"""A takeover or emergency stop this soon after an operator's e-stop press was caused by it."""
DEPARTED_MPS = 0.3
"""Speed at which a shuttle counts as having left a stop (dwell ends)."""
TABLE_EVENTS = (
    EventKind.COLLISION,
    EventKind.TAKEOVER,
    EventKind.RULE_VIOLATION,
    EventKind.EMERGENCY_STOP,
    EventKind.OPERATOR_ESTOP,
    EventKind.OPERATOR_RELEASE,
    EventKind.STACK_CRASH,
    EventKind.HARDWARE_WATCHDOG,
    EventKind.STOP_MISSED,
)
"""Events listed one by one (stop visits have their own table, TTC samples are merged per encounter)."""


def md(text: str) -> str:
    """Text safe inside a Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ")


def failed_checks(
    log: run_log.RunLog, metrics: Mapping[str, object], sig: run_signals.RunSignals
) -> list[str]:
    """One line per check the run failed, saying what was measured, when, and the limit."""
    out: list[str] = []
    for e in log.events_of(EventKind.COLLISION):
        d = e.data
        fault = "at fault" if d["at_fault"] else "not at fault"
        out.append(
            f"collision: with {d['agent_class']} {d['agent_id']} at {e.t_s:.1f} s, "
            f"{d['ego_speed_mps']:.1f} m/s, {fault}"
        )
    if metrics.get("comfort_compliant") == 0:
        out += [f"comfort: {e.describe()}" for e in sig.comfort_exceedances()]
    min_ttc = metrics.get("min_ttc_s")
    if metrics.get("ttc_compliant") == 0 and isinstance(min_ttc, int | float):
        worst = min(log.events_of(EventKind.MIN_TTC), key=lambda e: float(e.data["ttc_s"]))
        cls = report_views.road_user_classes(log).get(int(worst.data["agent_id"]), "road user")
        out.append(
            f"time to collision: {min_ttc:.2f} s at {worst.t_s:.1f} s ({cls} {worst.data['agent_id']}) "
            f"is below {metrics_mod.TTC_THRESHOLD_S:.2f} s"
        )
    for e in log.events_of(EventKind.TAKEOVER):
        out.append(f"takeover at {e.t_s:.1f} s: {cause_of(log, e) or e.data['reason']}")
    for e in log.events_of(EventKind.RULE_VIOLATION):
        out.append(f"rule {e.data['rule']} at {e.t_s:.1f} s: {e.data['detail']}")
    for e in log.events_of(EventKind.STOP_MISSED):
        out.append(f"stop {e.data['stop_id']} missed at {e.t_s:.1f} s with {e.data['waiting']} waiting")
    for e in log.events_of(EventKind.STACK_CRASH):
        out.append(f"vehicle software crashed at {e.t_s:.1f} s: {e.data['error']}")
    progress = metrics.get("progress_ratio")
    if isinstance(progress, float) and progress < metrics_mod.MIN_PROGRESS_RATIO:
        out.append(
            f"progress: {progress:.2f} of the expected route is below {metrics_mod.MIN_PROGRESS_RATIO:.2f}"
        )
    return out


def cause_of(log: run_log.RunLog, event: run_log.RunEvent) -> str:
    """The real cause of a takeover or an emergency stop when the run log knows it, else ""."""
    presses = [
        p for p in log.events_of(EventKind.OPERATOR_ESTOP) if 0.0 <= event.t_s - p.t_s <= CAUSE_WINDOW_S
    ]
    if presses:
        p = presses[-1]
        return f"operator e-stop pressed at {p.t_s:.2f} s in state {p.data['state']}"
    faults = [f for f in log.events_of(EventKind.FAULT_START) if f.t_s <= event.t_s]
    ended = {
        (f.data["kind"], f.data["target"]) for f in log.events_of(EventKind.FAULT_END) if f.t_s <= event.t_s
    }
    active = [f for f in faults if (f.data["kind"], f.data["target"]) not in ended]
    if active:
        f = active[-1]
        return f"injected fault {f.data['kind']}:{f.data['target']} since {f.t_s:.1f} s"
    return _safety_cause(log, event)


SAFETY_LEVELS = ("MINIMAL_RISK_MANOEUVRE", "EMERGENCY_STOP")
"""Vehicle-safety levels that ask for a takeover (a run's ``safety`` events carry the level by name)."""


def _safety_cause(log: run_log.RunLog, event: run_log.RunEvent) -> str:
    """The vehicle safety's directive behind a takeover the stack requested: its level, manoeuvre and
    the monitors' reasons (a GNSS outage's minimal-risk stop says why the pose was lost)."""
    directives = [
        s
        for s in log.events_of(EventKind.SAFETY)
        if 0.0 <= event.t_s - s.t_s <= CAUSE_WINDOW_S and s.data.get("level") in SAFETY_LEVELS
    ]
    if not directives:
        return ""
    d = directives[-1].data
    level = str(d["level"]).lower().replace("_", " ")
    mrm = f" ({str(d['mrm']).lower().replace('_', ' ')})" if d.get("mrm") not in (None, "NONE") else ""
    return f"vehicle safety's {level}{mrm} at {directives[-1].t_s:.2f} s: {d.get('reason', '')}"


def events_table(log: run_log.RunLog, max_rows: int) -> list[str]:
    """Incidents and operator actions with their cause, then one row per encounter (TTC merged)."""
    rows: list[tuple[float, str, str]] = []
    for e in log.events_of(*TABLE_EVENTS):
        details = ", ".join(f"{k}={v}" for k, v in e.data.items())
        cause = cause_of(log, e) if e.kind in (EventKind.TAKEOVER, EventKind.EMERGENCY_STOP) else ""
        rows.append((e.t_s, str(e.kind), f"{details}; cause: {cause}" if cause else details))
    for enc in report_views.encounters(log):
        if enc.collision:
            continue
        span = (
            f"{enc.t_start_s:.1f}-{enc.t_end_s:.1f} s"
            if enc.t_end_s > enc.t_start_s
            else f"{enc.t_start_s:.1f} s"
        )
        rows.append(
            (
                enc.t_min_s,
                "encounter",
                f"{enc.agent_class} {enc.agent_id}: min TTC {enc.min_ttc_s:.2f} s "
                f"({len(enc.samples)} samples, {span})",
            )
        )
    if not rows:
        return [
            "No collisions, takeovers, violations, emergency stops, missed stops or close encounters.",
            "",
        ]
    rows.sort(key=lambda r: r[0])
    lines = ["| t [s] | kind | details |", "|---:|---|---|"]
    lines += [f"| {t:.2f} | {kind} | {md(text)} |" for t, kind, text in rows[:max_rows]]
    if len(rows) > max_rows:
        lines.append(f"| | | {len(rows) - max_rows} more not listed |")
    return [*lines, ""]


def _left_waiting(data: Mapping[str, Any]) -> str:
    """Riders still at the stop when the door closed, "(full)" when no seat was free; "n/a" for a log
    written before the field existed."""
    left = data.get("left_waiting")
    if not isinstance(left, int):
        return "n/a"
    return f"{left} (full)" if left and data.get("seats_free") == 0 else str(left)


def stops_table(log: run_log.RunLog) -> list[str]:
    """One row per stop visit: arrival (doors open), dwell until the shuttle moved on, curb gap,
    longitudinal error, riders boarded and alighted, riders left waiting as the door closed (no seat,
    or arrived after boarding ended); missed stops with the riders left waiting."""
    served = log.events_of(EventKind.STOP_SERVED)
    missed = log.events_of(EventKind.STOP_MISSED)
    if not served and not missed:
        return ["No stop visited.", ""]
    t, v = log.column("t_s"), np.abs(log.column("speed_mps"))
    rows: list[tuple[float, str]] = []
    for e in served:
        d = e.data
        moving = np.flatnonzero((t > e.t_s) & (v >= DEPARTED_MPS))
        dwell = f"{float(t[moving[0]]) - e.t_s:.1f}" if len(moving) else "still there"
        rows.append(
            (
                e.t_s,
                f"| {md(str(d['stop_id']))} | {e.t_s:.1f} | {dwell} | {d['curb_gap_m']:.2f} | "
                f"{d['longitudinal_error_m']:.2f} | {d['boarded']} | {d['alighted']} | {_left_waiting(d)} |",
            )
        )
    for e in missed:
        rows.append(
            (
                e.t_s,
                f"| {md(str(e.data['stop_id']))} | missed at {e.t_s:.1f} | - | - | - | - | - "
                f"| {e.data['waiting']} |",
            )
        )
    rows.sort(key=lambda r: r[0])
    header = [
        "| stop | arrival [s] | dwell [s] | curb gap [m] | longitudinal error [m] | boarded | alighted "
        "| left waiting |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    return [*header, *(row for _, row in rows), ""]


def drop_offs_table(log: run_log.RunLog) -> list[str]:
    """Passengers' drop-off requests (the seat's button) and where each was served: at the kerb or,
    with no safe place before it, at the next stop. Nothing for a run without requests."""
    asked = log.events_of(EventKind.DROP_OFF_REQUESTED)
    if not asked:
        return []
    served = {e.data["passenger_id"]: e for e in log.events_of(EventKind.DROP_OFF_SERVED)}
    lines = [
        "### Drop-offs",
        "",
        "| passenger | pressed [s] | at route s [m] | served at | moved off [s] | route s [m] | curb gap [m] "
        "| standing [s] |",
        "|---:|---:|---:|---|---:|---:|---:|---:|",
    ]
    for e in asked:
        pid = e.data["passenger_id"]
        head = f"| {pid} | {e.t_s:.1f} | {float(e.data['route_s_m']):.1f} "
        got = served.get(pid)
        if got is None:
            lines.append(head + "| not served | - | - | - | - |")
            continue
        d = got.data
        where = f"stop {md(str(d['stop_id']))}" if d["stop_id"] else "kerb"
        lines.append(
            head + f"| {where} | {got.t_s:.1f} | {float(d['route_s_m']):.1f} | {float(d['curb_gap_m']):.2f} "
            f"| {float(d['wait_s']):.1f} |"
        )
    return [*lines, ""]


def yield_lines_table(log: run_log.RunLog) -> list[str]:
    """Each passage of a give-way line or a two-way stop's line (the referee's ``give_way_entry``): did
    the shuttle stand before it, and how long. Nothing for a run that crossed none."""
    entries = log.events_of(EventKind.GIVE_WAY_ENTRY)
    if not entries:
        return []
    lines = [
        "### Give-way lines and two-way stops",
        "",
        "| crossed [s] | line | kind | stood before | standing [s] |",
        "|---:|---:|---|---|---:|",
    ]
    for e in entries:
        d = e.data
        stood = "yes" if d["stopped_before"] else "no"
        kind = md(str(d["line_kind"]))
        lines.append(f"| {e.t_s:.1f} | {d['stop_line_id']} | {kind} | {stood} | {float(d['stood_s']):.1f} |")
    return [*lines, ""]


def state_timeline(log: run_log.RunLog, max_rows: int) -> list[str]:
    """The behaviour states in the order the stack took them, with how long each lasted."""
    changes = log.events_of(EventKind.STATE_CHANGE)
    if not changes:
        return ["No behaviour state recorded.", ""]
    end = float(log.column("t_s")[-1]) if len(log) else changes[-1].t_s
    lines = ["| from [s] | state | for [s] | reason |", "|---:|---|---:|---|"]
    for e, nxt in list(zip(changes, [*changes[1:], None], strict=True))[:max_rows]:
        until = nxt.t_s if nxt is not None else end
        lines.append(f"| {e.t_s:.1f} | {e.data['to']} | {until - e.t_s:.1f} | {md(str(e.data['reason']))} |")
    if len(changes) > max_rows:
        lines.append(f"| | | | {len(changes) - max_rows} more changes not listed |")
    return [*lines, ""]


def bulleted(items: Sequence[str], none: str) -> list[str]:
    return [*(f"- {md(i)}" for i in items), ""] if items else [none, ""]
