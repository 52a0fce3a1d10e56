"""The localization mode and what held the pose over a run, from its ``localization`` events."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from lastmile.core.run_events import EventKind
from lastmile.recorder.run_log import RunLog


@dataclass(frozen=True, slots=True, kw_only=True)
class LocalizationSpan:
    """An interval with one pose source and one GNSS state.

    Attributes:
        start_s, end_s: the span, simulated s.
        source: "gnss", "landmarks", "scan_matching", "amcl", "dead_reckoning" or "invalid" (no valid pose).
        gnss: the fix the vehicle received: "rtk_fixed", "rtk_float", "dgnss", "single", "no_fix" or
            "none_yet".
        pos_std_m: the estimate's position sigma when the span began, m.
    """

    start_s: float
    end_s: float
    source: str
    gnss: str
    pos_std_m: float


def localization_mode(log: RunLog) -> str:
    """The configured localization mode (``[stack] localization``), or "not recorded"."""
    run_config: Mapping[str, Any] = log.meta.config.get("run_config", {}) if log.meta.config else {}
    stack = run_config.get("stack", {}) if isinstance(run_config, Mapping) else {}
    return str(stack.get("localization", "not recorded")) if isinstance(stack, Mapping) else "not recorded"


def localization_spans(log: RunLog, end_s: float) -> list[LocalizationSpan]:
    """The run cut at each ``localization`` event, the last span ending at ``end_s``."""
    events = log.events_of(EventKind.LOCALIZATION)
    spans = []
    for i, e in enumerate(events):
        until = events[i + 1].t_s if i + 1 < len(events) else max(end_s, e.t_s)
        spans.append(
            LocalizationSpan(
                start_s=e.t_s,
                end_s=until,
                source=str(e.data["source"]),
                gnss=str(e.data["gnss"]),
                pos_std_m=float(e.data["pos_std_m"]),
            )
        )
    return spans


def localization_lines(log: RunLog, end_s: float, max_rows: int = 40) -> list[str]:
    """Markdown: the mode, the time per pose source and GNSS state, and the spans."""
    spans = localization_spans(log, end_s)
    lines = [f"Localization mode: **{localization_mode(log)}**.", ""]
    if not spans:
        return [*lines, "No localization events recorded.", ""]
    totals: dict[tuple[str, str], float] = {}
    for sp in spans:
        totals[(sp.source, sp.gnss)] = totals.get((sp.source, sp.gnss), 0.0) + sp.end_s - sp.start_s
    lines += ["| pose held by | GNSS | time [s] |", "|---|---|---:|"]
    lines += [f"| {src} | {gnss} | {t:.1f} |" for (src, gnss), t in sorted(totals.items())]
    lines += [
        "",
        "| from [s] | to [s] | pose held by | GNSS | position sigma at start [m] |",
        "|---:|---:|---|---|---:|",
    ]
    lines += [
        f"| {sp.start_s:.1f} | {sp.end_s:.1f} | {sp.source} | {sp.gnss} | {sp.pos_std_m:.3f} |"
        for sp in spans[:max_rows]
    ]
    if len(spans) > max_rows:
        lines.append(f"| | | | | {len(spans) - max_rows} more not listed |")
    return [*lines, ""]
