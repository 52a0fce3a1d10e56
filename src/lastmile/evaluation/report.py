"""The run report: ``report.md`` with Matplotlib PNGs of the path, the speed trace and ride comfort."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import NullLocator

from lastmile.core import vehicle_messages
from lastmile.core.errors import LastmileError
from lastmile.evaluation import metrics as metrics_mod
from lastmile.evaluation import report_html, report_pose, report_tables, report_views, run_signals
from lastmile.evaluation.localization_timeline import localization_lines
from lastmile.recorder import run_log

if TYPE_CHECKING:  # only for annotations: the report draws any object shaped like an HDMap
    from lastmile.hdmap.model import HDMap

REPORT_FILE = "report.md"
HTML_FILE = "report.html"
MAP_PNG = "map.png"
SPEED_PNG = "speed_accel.png"
COMFORT_PNG = "comfort.png"
LATENCY_PNG = "latency.png"

MAX_PLOT_POINTS = 4000
"""Ego samples drawn at most per trace; a 10-minute 50 Hz log is thinned about 8x, far below what shows."""

MAX_EVENT_ROWS = 200
"""Rows of the event table; the rest are counted, not listed."""

_DPI = 100
_STATE_COLOURS = ("#9ecae1", "#fdae6b", "#a1d99b", "#bcbddc", "#fdd0a2", "#fc9272")
_EVENT_STYLE: dict[str, dict[str, Any]] = {
    "collision": {"marker": "X", "color": "#d62728", "s": 90, "label": "collision"},
    "takeover": {"marker": "^", "color": "#ff7f0e", "s": 70, "label": "takeover"},
    "rule_violation": {"marker": "D", "color": "#c51b8a", "s": 45, "label": "rule violation"},
    "emergency_stop": {"marker": "s", "color": "#8c2d04", "s": 45, "label": "emergency stop"},
    "stop_served": {"marker": "o", "color": "#31a354", "s": 45, "label": "stop served"},
    "stop_missed": {"marker": "o", "color": "#000000", "s": 45, "label": "stop missed"},
}
_METRIC_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "Snow Lion Table 2",
        (
            "max_speed_mps",
            "mean_speed_mps",
            "share_time_at_or_above_9kph",
            "min_accel_mps2",
            "max_accel_mps2",
            "min_jerk_mps3",
            "max_jerk_mps3",
            "hard_braking_events",
            "km_per_hard_braking",
            "takeovers",
            "km_per_takeover",
            "distance_m",
            "duration_s",
        ),
    ),
    (
        "Closed-loop score",
        (
            "closed_loop_score",
            "progress_ratio",
            "ttc_compliant",
            "min_ttc_s",
            "speed_limit_compliance",
            "comfort_compliant",
            "comfort_violation",
        ),
    ),
    (
        "Ride comfort (10 Hz, outside emergencies)",
        (
            "comfort_min_accel_mps2",
            "comfort_max_accel_mps2",
            "comfort_min_jerk_mps3",
            "comfort_max_jerk_mps3",
            "snow_lion_comfort_compliant",
            "snow_lion_comfort_violation",
        ),
    ),
    ("Safety", ("collisions_total", "collisions_at_fault", "collisions_not_at_fault", "emergency_stops")),
    ("Takeovers by reason", tuple(f"takeovers_{r}" for r in run_log.TAKEOVER_REASONS)),
    (
        "Rules",
        (
            "rule_violations",
            *(f"rule_violations_{r}" for r in run_log.RULES),
            "rule_violations_other",
            "time_over_speed_limit_s",
            "intersection_entries",
            "intersection_entries_out_of_order",
        ),
    ),
    (
        "Service",
        (
            "stops_served",
            "stops_missed",
            "passengers_served",
            "passengers_boarded",
            "passengers_alighted",
            "mean_wait_s",
            "max_wait_s",
            "mean_ride_s",
            "max_ride_s",
            "pullover_curb_gap_mean_m",
            "pullover_curb_gap_max_m",
            "pullover_longitudinal_error_mean_m",
            "pullover_longitudinal_error_max_m",
            "loops_completed",
        ),
    ),
    (
        "Drop-offs",
        (
            "drop_offs_requested",
            "drop_offs_served",
            "drop_offs_at_kerb",
            "drop_off_curb_gap_max_m",
            "drop_off_wait_min_s",
        ),
    ),
    ("Share of time in each behaviour state", tuple(f"time_share_{s}" for s in run_log.STATE_NAMES)),
)


class ReportError(LastmileError):
    """The report cannot be written from what it was given (malformed timing, unwritable directory)."""


def _fmt(value: object) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        # Three decimals hide small jerks and gaps; those get significant digits instead.
        return f"{value:.3f}" if value == 0.0 or abs(value) >= 0.01 else f"{value:.2e}"
    return _md(str(value))


def _md(text: str) -> str:
    """Text safe inside a Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ")


def _thin(n: int) -> np.ndarray:
    step = max(1, int(np.ceil(n / MAX_PLOT_POINTS)))
    idx = np.arange(0, n, step)
    if n and idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return idx


def _event_xy(log: run_log.RunLog, events: Sequence[run_log.RunEvent]) -> np.ndarray:
    """(K, 2) ego positions at the events' times (interpolated in the trace)."""
    t = log.column("t_s")
    times = np.array([e.t_s for e in events])
    return np.c_[np.interp(times, t, log.column("x_m")), np.interp(times, t, log.column("y_m"))]


# --- (a) the map ---------------------------------------------------------------------------------------
def _map_figure(log: run_log.RunLog) -> Figure:
    """A figure shaped like the driven area, so that a long straight run is not a strip in a square."""
    width_in = 10.0
    if len(log) < 2:
        return Figure(figsize=(width_in, 7.0), dpi=_DPI, layout="constrained")
    span = np.ptp(np.c_[log.column("x_m"), log.column("y_m")], axis=0) + 40.0
    height_in = float(np.clip(width_in * span[1] / span[0], 1.5, 12.0)) + 1.6  # + title and colour bar
    return Figure(figsize=(width_in, height_in), dpi=_DPI, layout="constrained")


def _plot_map(log: run_log.RunLog, hdmap: HDMap | None, path: Path) -> None:
    fig = _map_figure(log)
    ax = fig.add_subplot()
    if hdmap is not None:
        report_views.draw_hdmap(ax, hdmap, label_stops=True)
    n = len(log)
    if n >= 2:
        idx = _thin(n)
        xy = np.c_[log.column("x_m")[idx], log.column("y_m")[idx]]
        speed = log.column("speed_mps")[idx]
        segments = np.stack([xy[:-1], xy[1:]], axis=1)
        norm = Normalize(vmin=0.0, vmax=max(float(np.max(speed)), 0.1))
        path_lines = LineCollection(list(segments), cmap="viridis", norm=norm, linewidths=2.0, zorder=3)
        path_lines.set_array(speed[:-1])
        ax.add_collection(path_lines)
        fig.colorbar(path_lines, ax=ax, label="speed [m/s]", location="bottom", shrink=0.6, aspect=40)
        ax.plot(*xy[0], marker="o", color="k", ms=6, zorder=4, label="start")
        road_users = report_views.draw_road_users(ax, log)
        for kind, style in _EVENT_STYLE.items():
            events = log.events_of(kind)
            if events:
                exy = _event_xy(log, events)
                ax.scatter(exy[:, 0], exy[:, 1], zorder=5, edgecolors="k", linewidths=0.5, **style)
                if kind in ("stop_served", "stop_missed") and hdmap is None:
                    for e, p in zip(events, exy, strict=True):
                        ax.annotate(
                            str(e.data["stop_id"]), p, xytext=(4, 4), textcoords="offset points", fontsize=8
                        )
        # Frame the driven path: the whole campus around a short run would leave it a dot.
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        pad = max(20.0, 0.08 * float(np.max(hi - lo)))
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        handles, _ = ax.get_legend_handles_labels()
        ax.legend(handles=[*handles, *road_users], loc="best", fontsize=7, markerscale=0.8)
    else:
        ax.text(0.5, 0.5, "no ego samples", ha="center", va="center", transform=ax.transAxes)
        if hdmap is not None:
            ax.autoscale_view()
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("Driven path coloured by speed")
    fig.savefig(path, dpi=_DPI)


# --- (b) speed and acceleration over time ---------------------------------------------------------------
def _state_bands(ax: Any, t: np.ndarray, state: np.ndarray) -> list[Patch]:
    patches: list[Patch] = []
    if len(t) < 2:
        return patches
    ends = np.append(t[1:], t[-1])
    for code, name in enumerate(run_log.STATE_NAMES):
        runs = run_signals.true_runs(state == code)
        if not runs:
            continue
        ranges = [(float(t[a]), float(ends[b - 1] - t[a])) for a, b in runs]
        colour = _STATE_COLOURS[code % len(_STATE_COLOURS)]
        ax.broken_barh(
            ranges, (0.0, 1.0), transform=ax.get_xaxis_transform(), facecolors=colour, alpha=0.35, zorder=0
        )
        patches.append(Patch(facecolor=colour, alpha=0.35, label=name))
    return patches


def _plot_speed(log: run_log.RunLog, sig: run_signals.RunSignals, path: Path) -> None:
    fig = Figure(figsize=(11.0, 6.0), dpi=_DPI, layout="constrained")
    ax_v, ax_a = fig.subplots(2, 1, sharex=True)
    n = len(log)
    if n:
        idx = _thin(n)
        t = log.column("t_s")
        state = log.column("state_code").astype(np.int64)
        patches = _state_bands(ax_v, t, state)
        _state_bands(ax_a, t, state)
        ax_v.plot(t[idx], log.column("speed_mps")[idx], color="#08519c", lw=1.2, label="speed")
        ax_v.axhline(metrics_mod.SPEED_9KPH_MPS, color="k", ls=":", lw=0.8, label="9 km/h")
        limit = log.meta.config.get("speed_limit_mps")
        if isinstance(limit, int | float) and not isinstance(limit, bool):
            ax_v.axhline(float(limit), color="#d62728", ls="--", lw=0.8, label="speed limit")
        ax_a.plot(t[idx], log.column("accel_mps2")[idx], color="#bdbdbd", lw=0.6, label="logged")
        ax_a.plot(sig.accel_10hz_t_s, sig.accel_10hz_mps2, color="#252525", lw=1.0, label="0.1 s mean")
        ax_a.axhline(sig.comfort.max_accel_mps2, color="#d62728", ls="--", lw=0.8, label="comfort limits")
        ax_a.axhline(-sig.comfort.max_decel_mps2, color="#d62728", ls="--", lw=0.8)
        ax_a.axhline(sig.comfort.hard_braking_mps2, color="#ff7f0e", ls=":", lw=0.8, label="hard braking")
        for kind, colour in (("collision", "#d62728"), ("takeover", "#ff7f0e")):
            for e in log.events_of(kind):
                for ax in (ax_v, ax_a):
                    ax.axvline(e.t_s, color=colour, lw=1.0)
        handles, _ = ax_v.get_legend_handles_labels()
        # Legends outside the axes: inside they would hide the trace they explain.
        ax_v.legend(handles=[*handles, *patches], loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
        ax_a.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
        ax_v.set_ylim(bottom=min(0.0, float(np.min(log.column("speed_mps")))))
    ax_v.set_ylabel("speed [m/s]")
    ax_a.set_ylabel("acceleration [m/s²]")
    ax_a.set_xlabel("time [s]")
    ax_v.set_title(
        "Speed and acceleration (bands: behaviour state; lines: collisions red, takeovers orange)", fontsize=9
    )
    fig.savefig(path, dpi=_DPI)


# --- (c) comfort histograms -----------------------------------------------------------------------------
def _plot_comfort(sig: run_signals.RunSignals, path: Path) -> None:
    fig = Figure(figsize=(10.0, 4.0), dpi=_DPI, layout="constrained")
    ax_a, ax_j = fig.subplots(1, 2)
    c = sig.comfort
    for ax, values, limits, label in (
        (ax_a, sig.accel_10hz_mps2, (-c.max_decel_mps2, c.max_accel_mps2), "acceleration [m/s²]"),
        (ax_j, sig.jerk_mps3, (-c.max_abs_jerk_mps3, c.max_abs_jerk_mps3), "jerk [m/s³]"),
    ):
        if len(values):
            # Span the limits too, so that the spread reads against them at a glance.
            span = (min(limits[0], float(np.min(values))), max(limits[1], float(np.max(values))))
            ax.hist(values, bins=80, range=span, color="#6baed6", edgecolor="none", log=True)
            ax.set_ylim(bottom=0.8)
        else:
            ax.text(0.5, 0.5, "no samples", ha="center", va="center", transform=ax.transAxes)
        for limit in limits:
            ax.axvline(limit, color="#d62728", ls="--", lw=1.0)
        ax.set_xlabel(label + " (0.1 s means)")
        ax.set_ylabel("count of 0.1 s samples")
    ax_a.axvline(c.hard_braking_mps2, color="#ff7f0e", ls=":", lw=1.0)
    ax_a.set_title("Acceleration (red: comfort limits, orange: hard braking)", fontsize=9)
    ax_j.set_title("Jerk (red: comfort limit)", fontsize=9)
    fig.savefig(path, dpi=_DPI)


# --- (d) per-module latency -------------------------------------------------------------------------
def _plot_latency(timing: Mapping[str, Any], path: Path) -> bool:
    """One histogram per module of its steady-state call times (log scale) with its cycle budget.
    False (nothing written) when the timing holds no histograms (an older log, no modules)."""
    modules = timing.get("modules", {})
    rows = [(n, r) for n, r in sorted(modules.items()) if isinstance(r, Mapping) and r.get("histogram")]
    if not rows:
        return False
    edges = np.asarray(vehicle_messages.LATENCY_HISTOGRAM_EDGES_MS)
    cols = min(4, len(rows))
    fig = Figure(figsize=(3.2 * cols, 2.6 * -(-len(rows) // cols)), dpi=_DPI, layout="constrained")
    axes = np.atleast_1d(fig.subplots(-(-len(rows) // cols), cols)).ravel()
    for ax, (name, row) in zip(axes, rows, strict=False):
        counts = np.asarray(row["histogram"], dtype=float)
        ax.stairs(counts, edges, fill=True, color="#6baed6")
        ax.set_xscale("log")
        # Seven decades of minor log ticks per panel were most of this plot's cost (0.8 of 1.4 CPU s, paid
        # by every run); the decade ticks and the budget line carry what the panel says.
        ax.xaxis.set_minor_locator(NullLocator())
        budget, over = row.get("budget_ms"), row.get("over_budget")
        if isinstance(budget, int | float):
            ax.axvline(float(budget), color="#d62728", ls="--", lw=1.0)
        title = f"{name}: {over} of {row.get('calls')} over {budget:g} ms" if budget else name
        ax.set_title(title, fontsize=8)
        ax.set_xlabel("call time [ms]", fontsize=7)
        ax.tick_params(labelsize=6)
    for ax in axes[len(rows) :]:
        ax.set_axis_off()
    fig.savefig(path, dpi=_DPI)
    return True


# --- report.md -----------------------------------------------------------------------------------------
def _metrics_tables(metrics: Mapping[str, object]) -> list[str]:
    lines: list[str] = []
    shown: set[str] = set()
    for title, keys in _METRIC_GROUPS:
        present = [k for k in keys if k in metrics]
        if not present:
            continue
        lines += [f"### {title}", "", "| metric | value |", "|---|---|"]
        lines += [f"| {k} | {_fmt(metrics[k])} |" for k in present]
        lines.append("")
        shown.update(present)
    rest = sorted(k for k in metrics if k not in shown)
    if rest:
        lines += ["### All other metrics", "", "| metric | value |", "|---|---|"]
        lines += [f"| {k} | {_fmt(metrics[k])} |" for k in rest]
        lines.append("")
    return lines


def _timing_table(timing: Mapping[str, Any]) -> list[str]:
    lines = ["Wall-clock figures of this machine; they vary between identical runs and are not metrics.", ""]
    modules = timing.get("modules", {})
    if not isinstance(modules, Mapping):
        raise ReportError(f"timing.modules: expected a mapping of module name to figures, got {modules!r}")
    if modules:
        lines += [
            "| module | calls | p50 [ms] | p95 [ms] | max [ms] | warm-up [ms] | budget [ms] | over budget |",
            "|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for name in sorted(modules):
            row = modules[name]
            if not isinstance(row, Mapping):
                raise ReportError(
                    f"timing.modules.{name}: expected p50_ms, p95_ms, max_ms, calls, got {row!r}"
                )
            keys = ("calls", "p50_ms", "p95_ms", "max_ms", "warmup_ms", "budget_ms", "over_budget")
            cells = [_fmt(row.get(k)) for k in keys]
            lines.append(f"| {_md(name)} | " + " | ".join(cells) + " |")
        lines.append("")
    else:
        lines += ["No per-module timing recorded.", ""]
    if "realtime_factor" in timing:
        lines += [f"Real-time factor (simulated / wall-clock time): {_fmt(timing['realtime_factor'])}", ""]
    if "warmup_s" in timing:
        lines += [
            f"Warm-up (each module's first call, and calls in which Numba compiled or loaded kernels): "
            f"{_fmt(timing['warmup_s'])} s, "
            "kept out of the percentiles, the calls and the real-time factor above; with it, the "
            f"real-time factor is {_fmt(timing.get('realtime_factor_with_warmup'))}.",
            "",
        ]
    return lines


def write_report(
    log: run_log.RunLog,
    metrics: Mapping[str, object],
    run_dir: str | os.PathLike[str],
    hdmap: HDMap | None = None,
    comfort: run_signals.ComfortLimits = run_signals.SHUTTLE_COMFORT,
) -> Path:
    """Write ``report.md`` and its PNGs (map, speed/acceleration, comfort) into ``run_dir``.

    Args:
        log: the run log.
        metrics: the dict of :func:`lastmile.evaluation.metrics.compute_metrics`.
        run_dir: output directory, created if missing.
        hdmap: the map to draw under the path (lanelet bounds, crosswalks, stop curbs); optional.
        comfort: the limits drawn on the plots (use those the metrics were computed with).

    Returns:
        The path of ``report.md``.

    Raises:
        ReportError: the directory cannot be written or ``log.timing`` is malformed.
    """
    out = Path(run_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"{out}: expected a writable run directory, got {exc}") from None
    sig = run_signals.RunSignals(log, comfort)
    timing_lines = _timing_table(log.timing)
    if _plot_latency(log.timing, out / LATENCY_PNG):
        timing_lines += [f"![per-module latency histograms against the cycle budget]({LATENCY_PNG})", ""]
    _plot_map(log, hdmap, out / MAP_PNG)
    _plot_speed(log, sig, out / SPEED_PNG)
    _plot_comfort(sig, out / COMFORT_PNG)
    has_places = hdmap is not None and report_views.plot_places(log, hdmap, out / report_views.PLACES_PNG)
    closest = report_views.closest(report_views.encounters(log))
    has_encounters = report_views.plot_encounters(log, hdmap, closest, out / report_views.ENCOUNTERS_PNG)
    has_pose_plot = report_pose.plot_pose_errors(sig.pose_errors, out / report_pose.POSE_PNG)
    meta = log.meta
    lines = [
        f"# Run report: {_md(meta.scenario_name)}",
        "",
        "| seed | weather | perception mode | scenario | map | simulated duration [s] |",
        "|---:|---|---|---|---|---:|",
        f"| {meta.seed} | {_md(meta.weather)} | **{_md(meta.perception_mode)}** | "
        f"{_md(meta.scenario_name)} | {_md(meta.map_name)} | {_fmt(sig.duration_s)} |",
        "",
    ]
    if log.timing.get("interrupted"):
        lines += [
            f"> **Interrupted** (Ctrl-C or SIGTERM) after {_fmt(sig.duration_s)} s of the "
            f"{_fmt(meta.duration_s)} s planned: everything below covers the time simulated.",
            "",
        ]
    if meta.perception_mode == "oracle":
        lines += ["> Perception mode **oracle**: the stack saw ground truth. This run is an ablation.", ""]
    lines += [
        "## Checks failed",
        "",
        *report_tables.bulleted(report_tables.failed_checks(log, metrics, sig), "None."),
        "## Map",
        "",
        f"![driven path coloured by speed, with events and other road users' tracks]({MAP_PNG})",
        "",
        *(
            [
                "## Stops and intersections",
                "",
                f"![each stop and intersection up close]({report_views.PLACES_PNG})",
                "",
            ]
            if has_places
            else []
        ),
        *(
            [
                "## Closest encounters",
                "",
                "Every collision and the closest approaches: the scene around the closest moment (dots: "
                "both at that moment) over the time-to-collision samples.",
                "",
                f"![encounter views]({report_views.ENCOUNTERS_PNG})",
                "",
            ]
            if has_encounters
            else []
        ),
        "## Stops",
        "",
        *report_tables.stops_table(log),
        *report_tables.drop_offs_table(log),
        *report_tables.yield_lines_table(log),
        "## Speed and acceleration",
        "",
        f"![speed and acceleration over time with behaviour states]({SPEED_PNG})",
        "",
        "## Comfort",
        "",
        f"![acceleration and jerk histograms with comfort limits]({COMFORT_PNG})",
        "",
        "## Metrics",
        "",
        *_metrics_tables(metrics),
        "## Events",
        "",
        *report_tables.events_table(log, MAX_EVENT_ROWS),
        "## Localization",
        "",
        *localization_lines(log, sig.duration_s),
        "### Localization and cross-track error",
        "",
        *report_pose.pose_error_lines(sig.pose_errors, has_pose_plot),
        "## Behaviour states",
        "",
        *report_tables.state_timeline(log, MAX_EVENT_ROWS),
        "## Compute time",
        "",
        *timing_lines,
    ]
    path = out / REPORT_FILE
    path.write_text("\n".join(lines), encoding="utf-8")
    report_html.write_html(lines, out, out / HTML_FILE, title=f"Run report: {meta.scenario_name}")
    return path
